"""The reference rows of a task's leaderboard: the fast learner (PPO) with each of the paper's
three networks, 3 seeds, from scratch or as a residual over the car-aware script, trained on the
task's train split and scored by the benchmark beside the scripts.

    python -m sharedspace.bench.rows crowd --arm residual [--frames 1500000] [--seeds 0 1 2]
        [--networks g_sac_cog g_sac_nocog s_sac] [--out results/bench]

Each run trains in its own process (``python -m sharedspace.train``) into
``OUT/runs/TASK-ARM-NETWORK-sSEED`` (config, metrics with the test-split curve, checkpoints);
a finished run is kept, an unfinished one resumes from its last checkpoint. Its last checkpoint
is the run's policy (nothing is chosen on the test scenes), shipped without its learner state
as ``OUT/policies/TASK-ARM-NETWORK-sSEED.pt``. Then every network's seeds are scored as one
pooled row (``OUT/TASK/ARM-NETWORK.json`` / ``.md``) against the task's ``car_aware`` row, and
the paper's question is asked of the rows: Cog − NoCog and Cog − S, paired. ``OUT/TASK/runs.json``
keeps each run's wall time.

The recipe (the trainer's PPO defaults and ``TRAIN_WORLDS``) was chosen on a validation split
carved from the train scenes (results/ppo/tuning), never on the test scenes.
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import time
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import torch

from sharedspace.bench.score import Result, compare, load_result, score
from sharedspace.bench.tasks import REPO
from sharedspace.paper.demos import TRAINING_VARIATIONS  # Table II-G's learners' variations

__all__ = ["ARMS", "NETWORKS", "TRAIN_WORLDS", "main"]

#: The paper's three networks (``TrainConfig.variant``).
NETWORKS = ("g_sac_cog", "g_sac_nocog", "s_sac")
#: How a row's learner starts: from scratch, or as a residual over the car-aware script.
ARMS: dict[str, list[str]] = {"scratch": [], "residual": ["base_driver=car_aware"]}
#: Each single-car task's training world: its pool (train split), parameters and M.
TRAIN_WORLDS: dict[str, list[str]] = {
    "paper": ["scenario_pool=", "server_params=params/table2.json5", "max_agents=8"],
    "crowd": [
        "scenario_pool=out/table2g/pool-general.json",
        "server_params=params/table2g.json5",
        "max_agents=10",
    ],
}


def run_name(task: str, arm: str, network: str, seed: int) -> str:
    return f"{task}-{arm}-{network}-s{seed}"


def train_run(task: str, arm: str, network: str, seed: int, frames: int, out: Path) -> float:
    """Trains (or resumes, or keeps) one run; returns the seconds this call spent training."""
    log_dir = out / "runs" / run_name(task, arm, network, seed)
    last = log_dir / "checkpoints" / "last.pt"
    done = 0
    if last.is_file():
        done = int(torch.load(last, map_location="cpu", weights_only=False)["counters"]["frames"])
        if done >= frames:
            return 0.0
    overrides = [
        "algorithm=ppo",
        f"variant={network}",
        f"seed={seed}",
        f"total_frames={frames}",
        *TRAIN_WORLDS[task],
        f"variations={json.dumps(TRAINING_VARIATIONS)}",
        *ARMS[arm],
        "eval_interval=262144",
        "checkpoint_interval=524288",
        f"log_dir={log_dir}",
    ]
    cmd = [sys.executable, "-m", "sharedspace.train", "--set", *overrides]
    if done:
        cmd += ["--resume", str(last)]
    t0 = time.perf_counter()
    subprocess.run(cmd, check=True, cwd=REPO, stdout=subprocess.DEVNULL)
    return time.perf_counter() - t0


def ship(task: str, arm: str, network: str, seed: int, out: Path) -> Path:
    """The run's last checkpoint without its learner state: the policy a result names."""
    name = run_name(task, arm, network, seed)
    ckpt = torch.load(out / "runs" / name / "checkpoints" / "last.pt", weights_only=False)
    for key in ("learner", "optimizers", "torch_rng"):
        ckpt.pop(key, None)
    path = out / "policies" / f"{name}.pt"
    path.parent.mkdir(parents=True, exist_ok=True)
    torch.save(ckpt, path)
    return path


def reference(task: str, driver: str, out: Path) -> Result:
    """The scripted driver's row of ``task`` (played once, then read back)."""
    path = out / task / f"{driver}.json"
    if path.is_file():
        return load_result(path)
    result = score(task, driver)
    result.save(out)
    return result


def main(argv: Sequence[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="python -m sharedspace.bench.rows", description=__doc__)
    ap.add_argument("task", choices=sorted(TRAIN_WORLDS))
    ap.add_argument("--arm", choices=sorted(ARMS), required=True)
    ap.add_argument("--networks", nargs="+", default=list(NETWORKS), choices=NETWORKS)
    ap.add_argument("--seeds", nargs="+", type=int, default=[0, 1, 2])
    ap.add_argument("--frames", type=int, default=1_500_000, help="env frames per run")
    ap.add_argument("--out", default="results/bench")
    args = ap.parse_args(argv)
    out = Path(args.out)
    folder = out / args.task
    log_path = folder / "runs.json"
    folder.mkdir(parents=True, exist_ok=True)
    log: dict[str, Any] = json.loads(log_path.read_text()) if log_path.is_file() else {}

    for network in args.networks:
        for seed in args.seeds:
            name = run_name(args.task, args.arm, network, seed)
            spent = train_run(args.task, args.arm, network, seed, args.frames, out)
            if spent:
                entry = log.setdefault(name, {"frames": args.frames, "wall_s": 0.0})
                entry["wall_s"] += spent
                log_path.write_text(json.dumps(log, indent=1))
                print(f"{name}: trained in {spent / 60:.1f} min", flush=True)

    car_aware = reference(args.task, "car_aware", out)
    reference(args.task, "pursuit_3", out)
    rows: dict[str, Result] = {}
    for network in args.networks:
        policies = [str(ship(args.task, args.arm, network, s, out)) for s in args.seeds]
        rows[network] = score(
            args.task, policies, name=f"{args.arm}-{network}", reference=car_aware
        )
        rows[network].save(out)
        print(rows[network].markdown(), flush=True)
    question = {}
    for other in ("g_sac_nocog", "s_sac"):
        if "g_sac_cog" in rows and other in rows:
            question[f"g_sac_cog - {other}"] = compare(rows["g_sac_cog"], rows[other])
    if question:
        (folder / f"{args.arm}-question.json").write_text(json.dumps(question, indent=1))
        for key, c in question.items():
            print(f"{args.arm}: {key}: {c['diff']:+.3f} [{c['lo']:+.3f}, {c['hi']:+.3f}]")
    return 0


if __name__ == "__main__":
    sys.exit(main())
