"""Does an average of a run's recent policies play better than its last one? Replays a run's
snapshot checkpoints (``checkpoint_interval`` apart) and, at every ``--every``-th snapshot,
scores on the run's evaluation split (a validation split: this chooses a recipe):

- ``last``: the snapshot itself;
- ``ema<d>``: the exponential moving average of the snapshots' actor parameters up to it, with
  per-iteration decay ``d`` (``d ** iterations_between_snapshots`` per snapshot), the feature
  normalisation's statistics taken from the snapshot.

Usage: python benchmarks/policy_average.py results/ppo/tuning/RUN [--decays 0.98 0.99 0.995]
       [--every 2] [--json out.json]
"""

from __future__ import annotations

import argparse
import json
import re
from pathlib import Path

import torch

from sharedspace.train.checkpoint import read_checkpoint
from sharedspace.train.evaluation import evaluate_split
from sharedspace.train.learners import load_checkpoint_actor


def snapshots(run: Path) -> list[tuple[int, Path]]:
    found = []
    for path in (run / "checkpoints").glob("step_*.pt"):
        found.append((int(re.search(r"step_(\d+)", path.name)[1]), path))
    return sorted(found)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("run")
    ap.add_argument("--decays", type=float, nargs="+", default=[0.98, 0.99, 0.995])
    ap.add_argument("--every", type=int, default=2, help="score every N-th snapshot")
    ap.add_argument("--json", default="")
    args = ap.parse_args()
    snaps = snapshots(Path(args.run))
    cfg, actor = load_checkpoint_actor(str(snaps[0][1]))
    averages: dict[float, dict[str, torch.Tensor]] = {}
    rows = []
    for i, (frames, path) in enumerate(snaps):
        state = read_checkpoint(str(path))["actor"]
        gap = (frames - (snaps[i - 1][0] if i else 0)) / (
            cfg.algo.num_envs * cfg.algo.rollout_steps
        )
        for d in args.decays:
            w = d**gap
            avg = averages.setdefault(d, {k: v.clone() for k, v in state.items()})
            for k, v in state.items():
                if v.is_floating_point() and "norm" not in k:
                    avg[k].mul_(w).add_(v, alpha=1 - w)
                else:
                    avg[k].copy_(v)
        if (i + 1) % args.every:
            continue
        row = {"frames": frames}
        for name, params in [("last", state)] + [
            (f"ema{d}", averages[d]) for d in args.decays
        ]:
            actor.load_state_dict(params)
            summary = evaluate_split(
                cfg.world, actor, cfg.world.eval_split, cfg.seed, cfg.driving
            )["summary"]
            row[name] = summary["success"]
            row[f"{name}_collision"] = summary["collision"]
        rows.append(row)
        print(json.dumps(row), flush=True)
    names = ["last"] + [f"ema{d}" for d in args.decays]
    print("| frames | " + " | ".join(names) + " |")
    print("|---:|" + "---:|" * len(names))
    for row in rows:
        print(
            f"| {row['frames']:,} | "
            + " | ".join(f"{row[n]:.3f}" for n in names)
            + " |"
        )
    for n in names:
        vals = [row[n] for row in rows]
        mean = sum(vals) / len(vals)
        swing = sum(abs(a - b) for a, b in zip(vals[1:], vals[:-1], strict=True)) / max(
            len(vals) - 1, 1
        )
        print(f"{n}: mean {mean:.3f}, mean change between scorings {swing:.3f}")
    if args.json:
        Path(args.json).write_text(json.dumps(rows, indent=1))


if __name__ == "__main__":
    main()
