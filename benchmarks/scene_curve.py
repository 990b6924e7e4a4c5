"""The generalisation curve's runs: PPO from scratch on a task's recorded train scenes and on
composed scenes beside them (``scenes=N``, SPEC 5.2.2), one run per arm and seed, resumable.

    .venv/bin/python benchmarks/scene_curve.py --task paper --arms recorded,n1000,unlimited \\
        --seeds 0 --frames 3145728 --network gcn_uniform

Each run trains with the bench's from-scratch recipe (``sharedspace.arms.rows``: the learning
rate held for half the run, then annealed to 0) and scores on the validation split carved from
the recorded train scenes as it goes. A run lives in ``results/scenes/runs/<task>-<arm>-s<seed>``
(config, metrics.csv, checkpoints), and its last checkpoint is shipped to
``results/scenes/policies/<run>.pt``; one cut short (a session's end) resumes from its last
checkpoint on the next call, and a finished one (``done.json``: its last line and its wall
seconds, summed over the calls) is skipped. Nothing in the training reads a test scene.

``--report`` scores each finished run's last checkpoint on the recorded train scenes (each once,
as recorded: what it fits), the validation split (its last scoring, in the trainer's variations)
and the bench task's test scenes (``python -m sharedspace.bench TASK``, reported beside, never
chosen on), pooled per arm, into ``results/scenes/curve-<task>.json`` and the figure
``docs/figures/scene-curve-<task>.png``; ``score.json`` in a run's directory keeps its scores.
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
RUNS = REPO / "results" / "scenes" / "runs"
#: Each finished run's last checkpoint, shipped (the checkpoints folder stays local).
POLICIES = REPO / "results" / "scenes" / "policies"

#: The arms: the overrides each adds to the recipe.
ARMS: dict[str, list[str]] = {
    "recorded": [],
    # the cheap road: the task's training variations, wider (position noise 0.5 -> 1.0 m, start
    # offsets 2 -> 4 steps, desired speed +-0.2 -> +-0.3) and rotated by up to 30 degrees
    "variations": [
        'variations={"position_sigma": 1.0, "start_offset_steps": 4, '
        '"desired_speed_scale": 0.3, "mirror": true, "rotation_deg": 30}'
    ],
    "n1000": ["scenes=1000"],
    "n10000": ["scenes=10000"],
    "unlimited": ["scenes=-1"],
}

#: The pilots' budget in frames (issue 58's from-scratch budget, chosen there on validation).
DEFAULT_FRAMES = 3_145_728

#: The bench's from-scratch recipe (sharedspace.arms.rows: SCRATCH and its run settings).
RECIPE = [
    "algorithm=ppo",
    "anneal_lr=true",
    "anneal_start=0.5",
    "update_threads=1",
    "checkpoint_interval=524288",
    "validation_variations=80",
    "progress=false",
]


def run_one(task: str, arm: str, seed: int, frames: int, network: str) -> dict:
    """Trains (or resumes, or skips) one run; its ``done.json``."""
    budget = "" if frames == DEFAULT_FRAMES else f"-{frames / 2**20:g}M"
    log_dir = RUNS / f"{task}-{arm}{budget}-s{seed}"
    done = log_dir / "done.json"
    if done.is_file():
        return json.loads(done.read_text())
    wall = log_dir / "wall.json"
    spent = json.loads(wall.read_text())["seconds"] if wall.is_file() else 0.0
    overrides = [
        *RECIPE,
        f"task={task}",
        f"network={network}",
        f"seed={seed}",
        f"total_frames={frames}",
        f"log_dir={log_dir.relative_to(REPO)}",
        *ARMS[arm],
    ]
    cmd = [sys.executable, "-m", "sharedspace.train", "--set", *overrides]
    if (log_dir / "checkpoints").is_dir():
        cmd.append("--resume")
    print(f"[scene_curve] {' '.join(cmd[1:])}", flush=True)
    start = time.monotonic()
    proc = subprocess.run(cmd, cwd=REPO, capture_output=True, text=True)
    log_dir.mkdir(parents=True, exist_ok=True)
    spent += time.monotonic() - start
    wall.write_text(json.dumps({"seconds": spent}))
    (log_dir / "train.log").open("a").write(proc.stdout + proc.stderr)
    if proc.returncode != 0:
        raise SystemExit(
            f"{log_dir.name}: exit {proc.returncode}; see {log_dir}/train.log"
        )
    last = json.loads(proc.stdout.strip().splitlines()[-1])
    out = {
        "arm": arm + budget,
        "seed": seed,
        "task": task,
        "wall_seconds": spent,
        "result": last,
    }
    ship_policy(log_dir)
    done.write_text(json.dumps(out, indent=1))
    return out


def ship_policy(log_dir: Path) -> Path:
    """The run's last checkpoint, shipped to ``results/scenes/policies/<run>.pt`` (what the
    report scores, so a clean checkout can score it again)."""
    from sharedspace.train.checkpoint import last_checkpoint, read_checkpoint, ship

    return ship(
        read_checkpoint(last_checkpoint(str(log_dir))), POLICIES / f"{log_dir.name}.pt"
    )


def score_run(log_dir: Path, task: str) -> dict:
    """A finished run's last checkpoint on the recorded train scenes, the validation split and
    the bench task's test scenes (kept in the run's ``score.json``)."""
    kept = log_dir / "score.json"
    if kept.is_file() and "test_minus_car_aware" in json.loads(kept.read_text()):
        return json.loads(kept.read_text())
    from sharedspace.bench.scoring import score
    from sharedspace.train.evaluation import evaluate_split
    from sharedspace.train.learners import load_checkpoint_actor

    shipped = POLICIES / f"{log_dir.name}.pt"
    ckpt = str(shipped if shipped.is_file() else ship_policy(log_dir))
    cfg, actor = load_checkpoint_actor(ckpt)
    out = {"checkpoint": str(Path(ckpt).relative_to(REPO))}
    for split in ("train", "validation"):
        summary = evaluate_split(cfg.world, actor, split, cfg.seed, cfg.driving)[
            "summary"
        ]
        out[split] = {
            k: summary[k] for k in ("episodes", "success", "collision", "timeout")
        }
    rows = [
        ln.split(",") for ln in (log_dir / "metrics.csv").read_text().splitlines()[1:]
    ]
    trained = [float(r[3]) for r in rows if len(r) == 4 and r[2] == "train/success"]
    out["trained_on"] = {
        "success": trained[-1]
    }  # its own training scenes, as it played them
    script = REPO / "results" / "bench" / task / "car_aware.json"
    test = score(task, [ckpt], name=log_dir.name, reference=script)
    out["test"] = {
        "episodes": test.summary["episodes"],
        **{k: test.summary[k]["rate"] for k in ("success", "collision", "timeout")},
    }
    out["test_minus_car_aware"] = test.comparison
    kept.write_text(json.dumps(out, indent=1))
    return out


def _diff(row: dict) -> str:
    c = row.get("test_minus_car_aware")
    return "–" if not c else f"{c['diff']:+.3f} [{c['lo']:+.3f}, {c['hi']:+.3f}]"


def report(task: str) -> None:
    """Every finished run of ``task`` scored, pooled per arm, and a markdown table."""
    arms: dict[str, list[dict]] = {}
    for done in sorted(RUNS.glob(f"{task}-*-s*/done.json")):
        run = json.loads(done.read_text())
        run["score"] = score_run(done.parent, task)
        arms.setdefault(run["arm"], []).append(run)
    rows = {}
    head = (
        "| arm | seeds | frames | wall (min/run) | its training scenes (as played) | "
    )
    print(
        head
        + "recorded train scenes | validation | test success / collision | test − car_aware |"
    )
    print("|---|---|---|---|---|---|---|---|---|")
    for arm, runs in arms.items():
        mean = lambda split, key: sum(r["score"][split][key] for r in runs) / len(runs)  # noqa: E731
        rows[arm] = {
            "seeds": [r["seed"] for r in runs],
            "frames": runs[0]["result"]["counters"]["frames"],
            "wall_min": sum(r["wall_seconds"] for r in runs) / len(runs) / 60,
            **{
                split: {k: mean(split, k) for k in ("success", "collision", "timeout")}
                for split in ("train", "validation", "test")
            },
            "trained_on": {"success": mean("trained_on", "success")},
            # one seed: its paired difference; several: score them pooled with the bench
            "test_minus_car_aware": runs[0]["score"]["test_minus_car_aware"]
            if len(runs) == 1
            else None,
        }
        r = rows[arm]
        print(
            f"| {arm} | {len(runs)} | {r['frames']} | {r['wall_min']:.1f} | "
            f"{r['trained_on']['success']:.3f} | "
            f"{r['train']['success']:.3f} | {r['validation']['success']:.3f} | "
            f"{r['test']['success']:.3f} / {r['test']['collision']:.3f} | {_diff(r)} |"
        )
    (REPO / "results" / "scenes" / f"curve-{task}.json").write_text(
        json.dumps(rows, indent=1)
    )
    plot(task, rows, arms)


#: The arms in the order of the figure: from the recorded scenes to a fresh scene each episode.
ORDER = ["recorded", "variations", "n1000", "n10000", "unlimited"]


def _validation_curve(log_dir: Path) -> tuple[list[float], list[float]]:
    """(frames in millions, validation success) of a run's scorings."""
    rows = [
        ln.split(",") for ln in (log_dir / "metrics.csv").read_text().splitlines()[1:]
    ]
    points = [
        (int(r[0]) / 1e6, float(r[3]))
        for r in rows
        if len(r) == 4 and r[2] == "eval/success"
    ]
    return [p[0] for p in points], [p[1] for p in points]


def plot(task: str, rows: dict, arms: dict[str, list[dict]]) -> Path:
    """``docs/figures/scene-curve-TASK.png``: each arm's success on its own training scenes,
    the recorded train scenes, validation and test (left), and every run's validation curve
    (right), beside ``car_aware``'s test success."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    script = json.loads(
        (REPO / "results" / "bench" / task / "car_aware.json").read_text()
    )
    car_aware = script["summary"]["success"]["rate"]
    names = [a for a in ORDER if a in rows] + sorted(a for a in rows if a not in ORDER)
    fig, (left, right) = plt.subplots(1, 2, figsize=(12, 4.5))
    splits = [
        ("trained_on", "its own training scenes"),
        ("train", "recorded train scenes"),
        ("validation", "validation (12 x 80)"),
        ("test", "test (bench, 18 x 128)"),
    ]
    width = 0.2
    for k, (split, label) in enumerate(splits):
        xs = [i + (k - 1.5) * width for i in range(len(names))]
        left.bar(xs, [rows[a][split]["success"] for a in names], width, label=label)
    left.axhline(
        car_aware, color="k", ls="--", lw=1, label=f"car_aware test ({car_aware:.3f})"
    )
    ticks = [f"{a.split('-')[0]}\n{rows[a]['frames'] / 1e6:.2f} M" for a in names]
    left.set_xticks(range(len(names)), ticks, fontsize=8)
    left.set_ylim(0.4, 1.0)
    left.set_ylabel("success")
    left.set_title(f"{task}: PPO from scratch, gcn_uniform, seed 0")
    left.legend(fontsize=7, loc="lower right")
    for arm in names:
        for run in arms[arm]:
            frames, success = _validation_curve(RUNS / f"{task}-{arm}-s{run['seed']}")
            right.plot(frames, success, marker=".", label=arm)
    right.axhline(car_aware, color="k", ls="--", lw=1)
    right.set_xlabel("frames (M)")
    right.set_ylabel("validation success")
    right.set_title("validation during training (chosen on; test never)")
    right.legend(fontsize=7)
    fig.tight_layout()
    out = REPO / "docs" / "figures" / f"scene-curve-{task}.png"
    fig.savefig(out, dpi=110)
    plt.close(fig)
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--task", default="paper")
    ap.add_argument("--arms", default="recorded,n1000,unlimited")
    ap.add_argument("--seeds", default="0")
    ap.add_argument("--frames", type=int, default=DEFAULT_FRAMES, help="a run's budget")
    ap.add_argument("--network", default="gcn_uniform")
    ap.add_argument(
        "--report", action="store_true", help="score the finished runs instead"
    )
    args = ap.parse_args()
    if args.report:
        report(args.task)
        return
    arms = args.arms.split(",")
    for arm in arms:
        if arm not in ARMS:
            raise SystemExit(f"unknown arm {arm!r}: one of {', '.join(ARMS)}")
    for seed in (int(s) for s in args.seeds.split(",")):
        for arm in arms:
            out = run_one(args.task, arm, seed, args.frames, args.network)
            print(json.dumps(out), flush=True)


if __name__ == "__main__":
    main()
