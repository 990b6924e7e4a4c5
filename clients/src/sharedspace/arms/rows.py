"""The reference rows of a task's leaderboard: the fast learner (PPO) with each of the paper's
three networks, 3 seeds, from scratch or as a residual over the car-aware script, trained on the
task's train split and scored by the benchmark beside the scripts.

    python -m sharedspace.arms.rows crowd --arm residual [--frames 1500000] [--seeds 0 1 2]
        [--networks gcn_risk gcn_uniform mlp] [--out results/bench]

Each run trains for the task in its own process (``python -m sharedspace.train --set
task=TASK``) into ``OUT/runs/TASK-ARM-NETWORK-sSEED`` (config, metrics with the curve on the
validation split carved from the train scenes, checkpoints);
a finished run is kept, an unfinished one resumes from its last checkpoint. Its last checkpoint
is the run's policy (nothing is chosen on the test scenes), shipped without its learner state
as ``OUT/policies/TASK-ARM-NETWORK-sSEED.pt``. Then every network's seeds are scored as one
pooled row (``OUT/TASK/ARM-NETWORK.json`` / ``.md``) against the task's ``car_aware`` row, and
the paper's question is asked of the rows: Cog − NoCog and Cog − S, paired. ``OUT/TASK/runs.json``
keeps each run's wall time. Last, the task's best row is chosen on validation
(:mod:`sharedspace.arms.best`, ``OUT/best.json``) and its leaderboard written.

The recipe (the trainer's PPO defaults and the tasks' training worlds, :mod:`sharedspace.worlds`)
was chosen on a validation split carved from the train scenes (results/ppo/tuning), never on the
test scenes. The residual arm's shipped runs (2026-12-06) name their networks by the old names
(``s_sac``, ``g_sac_nocog``, ``g_sac_cog``), which ``--networks`` still accepts.
"""

from __future__ import annotations

import argparse
import itertools
import json
import subprocess
import sys
import time
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from sharedspace.arms.best import choose_best, validation_variations
from sharedspace.bench import leaderboard
from sharedspace.bench.scoring import Result, compare, load_result, score
from sharedspace.bench.tasks import REPO
from sharedspace.cli import run_command
from sharedspace.train.checkpoint import read_checkpoint
from sharedspace.train.checkpoint import ship as ship_checkpoint
from sharedspace.train.networks import NETWORKS as REGISTERED_NETWORKS
from sharedspace.train.networks import UnknownNetwork, canonical_network
from sharedspace.train.registry import get_algorithm
from sharedspace.worlds import TRAINING_TASKS

__all__ = ["ARMS", "NETWORKS", "main"]

#: The paper's three networks (those the registry gives a paper label), risk graph first.
NETWORKS = tuple(name for name, net in REGISTERED_NETWORKS.items() if net.sac_label)
#: How a row's learner starts: from scratch, or as a residual over the car-aware script. From
#: scratch the learning rate is held for half the run, then falls linearly to 0, so that the
#: last checkpoint is the run's policy (chosen on validation: docs/RESULTS.md, "Table II from
#: scratch").
ARMS: dict[str, list[str]] = {
    "scratch": ["anneal_lr=true", "anneal_start=0.5"],
    "residual": ["base_driver=car_aware"],
}
#: Frames between validation scorings (and checkpoints): PPO's own cadence, a multiple of its
#: batch (256 x 32 frames).
EVAL_INTERVAL = get_algorithm("ppo").config.eval_interval
#: The single-car tasks a row trains for.
SINGLE_CAR_TASKS = tuple(n for n, t in TRAINING_TASKS.items() if t.cars == 1)


def _network_name(name: str) -> str:
    """A ``--networks`` entry: a registered network or an alias (kept as given: the residual
    arm's shipped runs are named by the old names)."""
    try:
        canonical_network(name)
    except UnknownNetwork as err:
        raise argparse.ArgumentTypeError(str(err)) from None
    return name


def run_name(task: str, arm: str, network: str, seed: int) -> str:
    return f"{task}-{arm}-{network}-s{seed}"


def train_run(
    task: str, arm: str, network: str, seed: int, frames: int, out: Path, extra: Sequence[str] = ()
) -> float:
    """Trains (or resumes, or keeps) one run, with the trainer's ``--set`` items ``extra``
    after the arm's; returns the seconds this call spent training."""
    log_dir = out / "runs" / run_name(task, arm, network, seed)
    last = log_dir / "checkpoints" / "last.pt"
    done = 0
    if last.is_file():
        done = int(read_checkpoint(last)["counters"]["frames"])
        if done >= frames:
            return 0.0
    overrides = [
        "algorithm=ppo",
        f"task={task}",
        f"network={network}",
        f"seed={seed}",
        f"total_frames={frames}",
        *ARMS[arm],
        f"eval_interval={EVAL_INTERVAL}",
        f"validation_variations={validation_variations(task)}",  # 960 episodes or more
        f"checkpoint_interval={EVAL_INTERVAL}",
        f"log_dir={log_dir}",
        *extra,
    ]
    cmd = [sys.executable, "-m", "sharedspace.train", "--set", *overrides]
    if done:
        cmd += ["--resume", str(last)]
    t0 = time.perf_counter()
    subprocess.run(cmd, check=True, cwd=REPO, stdout=subprocess.DEVNULL)
    return time.perf_counter() - t0


#: A run is stable when its last three validation scorings span this many frames or more ...
STABLE_SPAN = 1_000_000
#: ... and lie within this of each other, and its last within :data:`SHIPPED_TOLERANCE` of their
#: mean (the shipped checkpoint is the last scoring's).
STABLE_RANGE, SHIPPED_TOLERANCE = 0.05, 0.03


def stability(log_dir: Path) -> dict[str, Any]:
    """A run's last three validation scorings (``eval/success`` and ``eval/episodes`` of its
    ``metrics.csv``) and whether they are stable: spanning :data:`STABLE_SPAN` frames, within
    :data:`STABLE_RANGE` of each other, the last within :data:`SHIPPED_TOLERANCE` of their
    mean."""
    scorings: dict[int, dict[str, float]] = {}
    with open(log_dir / "metrics.csv") as f:
        for line in f:
            parts = line.strip().split(",")
            if len(parts) == 4 and parts[2] in ("eval/success", "eval/episodes"):
                scorings.setdefault(int(parts[0]), {})[parts[2][5:]] = float(parts[3])
    last = sorted(scorings.items())[-3:]
    frames = [f for f, _ in last]
    success = [v["success"] for _, v in last]
    if len(last) < 3:
        return {"frames": frames, "success": success, "stable": False}
    mean = sum(success) / 3
    spread = max(success) - min(success)
    return {
        "frames": frames,
        "success": success,
        "episodes": [int(v.get("episodes", 0)) for _, v in last],
        "range": round(spread, 4),
        "last_minus_mean": round(success[-1] - mean, 4),
        "stable": frames[-1] - frames[0] >= STABLE_SPAN
        and spread <= STABLE_RANGE
        and abs(success[-1] - mean) <= SHIPPED_TOLERANCE,
    }


def ship(task: str, arm: str, network: str, seed: int, out: Path) -> Path:
    """The run's last checkpoint without its learner state: the policy a result names."""
    name = run_name(task, arm, network, seed)
    ckpt = read_checkpoint(out / "runs" / name / "checkpoints" / "last.pt")
    return ship_checkpoint(ckpt, out / "policies" / f"{name}.pt")


def reference(task: str, driver: str, out: Path) -> Result:
    """The scripted driver's row of ``task`` (played once, then read back)."""
    path = out / task / f"{driver}.json"
    if path.is_file():
        return load_result(path)
    result = score(task, driver)
    result.save(out)
    return result


def main(argv: Sequence[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="python -m sharedspace.arms.rows", description=__doc__)
    ap.add_argument("task", choices=SINGLE_CAR_TASKS)
    ap.add_argument("--arm", choices=sorted(ARMS), required=True)
    ap.add_argument("--networks", nargs="+", default=list(NETWORKS), type=_network_name)
    ap.add_argument("--seeds", nargs="+", type=int, default=[0, 1, 2])
    ap.add_argument(
        "--frames",
        type=int,
        default=1_500_000,
        help="env frames per run (a multiple of 524 288"
        " puts the last three scorings 1 M frames apart)",
    )
    ap.add_argument("--out", default="results/bench")
    ap.add_argument(
        "--set",
        nargs="*",
        default=[],
        metavar="KEY=VALUE",
        help="more trainer settings for every run (e.g. update_threads=1 beside another run)",
    )
    args = ap.parse_args(argv)
    out = Path(args.out)
    folder = out / args.task
    log_path = folder / "runs.json"
    folder.mkdir(parents=True, exist_ok=True)
    log: dict[str, Any] = json.loads(log_path.read_text()) if log_path.is_file() else {}

    for network in args.networks:
        for seed in args.seeds:
            name = run_name(args.task, args.arm, network, seed)
            spent = train_run(args.task, args.arm, network, seed, args.frames, out, args.set)
            if spent:
                entry = log.setdefault(name, {"frames": args.frames, "wall_s": 0.0})
                entry["wall_s"] += spent
                log_path.write_text(json.dumps(log, indent=1))
                print(f"{name}: trained in {spent / 60:.1f} min", flush=True)

    steady = {
        run_name(args.task, args.arm, n, s): stability(
            out / "runs" / run_name(args.task, args.arm, n, s)
        )
        for n in args.networks
        for s in args.seeds
    }
    (folder / f"{args.arm}-stability.json").write_text(json.dumps(steady, indent=1))
    for name, st in steady.items():
        print(f"{name}: last three validation scorings {st['success']}: stable {st['stable']}")

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
    by_network = {canonical_network(n): row for n, row in rows.items()}
    for a, b in itertools.combinations([n for n in NETWORKS if n in by_network], 2):
        question[f"{a} - {b}"] = compare(by_network[a], by_network[b])
    if question:
        (folder / f"{args.arm}-question.json").write_text(json.dumps(question, indent=1))
        for key, c in question.items():
            print(f"{args.arm}: {key}: {c['diff']:+.3f} [{c['lo']:+.3f}, {c['hi']:+.3f}]")
    best = choose_best([args.task], out)  # on validation: the test scores above play no part
    print(f"best row of {args.task}, chosen on validation: {best[args.task]['name']}")
    leaderboard.main([str(folder), "--out", str(folder / "LEADERBOARD.md")])
    return 0


if __name__ == "__main__":
    sys.exit(run_command(main))
