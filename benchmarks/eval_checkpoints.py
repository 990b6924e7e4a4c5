"""Every scene of a split (the test split by default; `--split train`: the scenes a run trained on)
once with each checkpoint's deterministic policy (the trainer's evaluation,
``sharedspace.train.evaluation.evaluate_split``), in the checkpoint's own world: what a run's
last checkpoint scores, for runs whose loop ended without a final evaluation.

Usage: python benchmarks/eval_checkpoints.py results/ppo/runs/*/checkpoints/last.pt [--json out.json]
"""

from __future__ import annotations

import argparse
import json

from sharedspace.train.checkpoint import describe, read_checkpoint
from sharedspace.train.evaluation import evaluate_split
from sharedspace.train.learners import load_checkpoint_actor


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("checkpoints", nargs="+")
    ap.add_argument("--split", default="test")
    ap.add_argument("--json", default="")
    args = ap.parse_args()
    out = {}
    for path in args.checkpoints:
        cfg, actor = load_checkpoint_actor(path)
        summary = evaluate_split(cfg.world, actor, args.split, cfg.seed, cfg.driving)[
            "summary"
        ]
        ckpt = read_checkpoint(path)
        out[path] = {"frames": ckpt["counters"]["frames"], **summary}
        print(
            f"{path}: {describe(ckpt)}: success {summary['success']:.3f}, "
            f"collision {summary['collision']:.3f}, timeout {summary['timeout']:.3f} "
            f"on {summary['episodes']} {args.split} scenes"
        )
    if args.json:
        with open(args.json, "w") as f:
            json.dump(out, f, indent=1)


if __name__ == "__main__":
    main()
