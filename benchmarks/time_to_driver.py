"""The time to a driver: from scratch on ``crowd`` with the GCN over the risk graph, the
wall-clock minutes and the frames until the validation success first reaches a threshold
(0.75), for two codes (before and after a change) and several seeds, interleaved on one box.

Each run is the reference arm's recipe (``python -m sharedspace.train --set task=crowd
algorithm=ppo network=gcn_risk seed=S anneal_lr=true anneal_start=0.5 total_frames=6291456``,
``sharedspace.arms.rows``'s ``scratch`` arm) with a validation scoring every ``--eval-interval``
frames (the split carved from the train scenes: nothing here looks at the test scenes). A run
is stopped at its first scoring at or above the threshold, or at ``--cap`` frames. Its minutes
are its training wall time at that scoring (collection and updates, ``eval/train_wall_s``: the
scorings' own time is left out, as it does not depend on the code). A code is a ``src``
folder put first on ``PYTHONPATH`` (see ``overlap_ab.py``).

Learning per frame: for each seed, both codes' validation success at the last scoring both
runs reached (matched frames), after − before, with two intervals: over the seeds (t, seeds
resampled) and over the scorings' episodes (normal, the seeds fixed).

Every finished run is kept in ``--out`` (JSON, with its curve): a rerun of the command skips
them, so the benchmark resumes where a session ended.

Usage: python benchmarks/time_to_driver.py --before /tmp/before/clients/src
       [--after-set ppo_epochs=2] [--seeds 0 1 2] [--cap 3145728]
       [--out results/time_to_driver/NAME.json]
"""

from __future__ import annotations

import argparse
import csv
import json
import math
import os
import signal
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from overlap_ab import ROOT, code_env  # benchmarks/, beside this script

from sharedspace.train.config import load_config
from sharedspace.worlds import validation_label

RECIPE = [
    "task=crowd",
    "algorithm=ppo",
    "network=gcn_risk",
    "anneal_lr=true",
    "anneal_start=0.5",
    "total_frames=6291456",
    "checkpoint_interval=0",
    "progress=false",
]
#: Student's t at 97.5 % for 1..4 degrees of freedom (a 95 % interval over few seeds).
T975 = {1: 12.706, 2: 4.303, 3: 3.182, 4: 2.776}


def curve(metrics: Path) -> list[dict]:
    """The run's validation scorings so far: frames, success, episodes, training wall time."""
    if not metrics.is_file():
        return []
    rows: dict[int, dict] = {}
    with metrics.open() as f:
        for r in csv.DictReader(f):
            name = r["metric"].removeprefix("eval/")
            if r["metric"].startswith("eval/") and name in (
                "success",
                "episodes",
                "train_wall_s",
            ):
                rows.setdefault(int(r["frames"]), {"frames": int(r["frames"])})[
                    name
                ] = float(r["value"])
    return [
        v for _, v in sorted(rows.items()) if "train_wall_s" in v and "success" in v
    ]


def one_run(src: str, seed: int, args, log_dir: Path, settings: list[str]) -> dict:
    """Trains until the threshold or the cap; the run's curve and where it crossed."""
    env = code_env(src)
    more = [f"seed={seed}", f"eval_interval={args.eval_interval}", f"log_dir={log_dir}"]
    cmd = [
        sys.executable,
        "-m",
        "sharedspace.train",
        "--set",
        *RECIPE,
        *more,
        *args.set,
    ]
    t0 = time.perf_counter()
    proc = subprocess.Popen(
        cmd, cwd=ROOT, env=env, stdout=subprocess.DEVNULL, start_new_session=True
    )
    crossed = None
    try:
        while proc.poll() is None:
            time.sleep(2.0)
            points = curve(log_dir / "metrics.csv")
            crossed = next((p for p in points if p["success"] >= args.threshold), None)
            if crossed or (points and points[-1]["frames"] >= args.cap):
                break
    finally:
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGTERM)  # the trainer and the server it started
            proc.wait(timeout=60)
    if proc.returncode not in (0, -signal.SIGTERM, None) and not crossed:
        raise SystemExit(f"run failed ({proc.returncode}): {' '.join(cmd)}")
    points = curve(log_dir / "metrics.csv")
    crossed = next((p for p in points if p["success"] >= args.threshold), None)
    return {
        "seed": seed,
        "frames_to_threshold": crossed["frames"] if crossed else None,
        "minutes_to_threshold": crossed["train_wall_s"] / 60 if crossed else None,
        "box_minutes": (time.perf_counter() - t0) / 60,
        "curve": points,
    }


def median_minutes(runs: list[dict]) -> float:
    """The median over seeds (a seed that never crossed counts as infinitely slow)."""
    return statistics.median(
        r["minutes_to_threshold"] if r["minutes_to_threshold"] is not None else math.inf
        for r in runs
    )


def per_frame(before: list[dict], after: list[dict]) -> dict:
    """after − before validation success at each seed's last matched scoring, with intervals
    over the seeds and over the scorings' episodes."""
    diffs, variances, frames = [], [], []
    for b, a in zip(before, after, strict=True):
        common = {p["frames"] for p in b["curve"]} & {p["frames"] for p in a["curve"]}
        if not common:
            continue
        f = max(common)
        pb = next(p for p in b["curve"] if p["frames"] == f)
        pa = next(p for p in a["curve"] if p["frames"] == f)
        diffs.append(pa["success"] - pb["success"])
        variances.append(
            pa["success"] * (1 - pa["success"]) / pa["episodes"]
            + pb["success"] * (1 - pb["success"]) / pb["episodes"]
        )
        frames.append(f)
    n = len(diffs)
    mean = sum(diffs) / n
    out = {"seeds": n, "frames": frames, "diffs": diffs, "mean": mean}
    if n > 1:
        half = T975.get(n - 1, 1.96) * statistics.stdev(diffs) / math.sqrt(n)
        out["interval_seeds"] = [mean - half, mean + half]
    half = 1.96 * math.sqrt(sum(variances)) / n
    out["interval_episodes"] = [mean - half, mean + half]
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--before", required=True, help="clients/src of the code before")
    ap.add_argument(
        "--after", default=str(ROOT / "clients" / "src"), help="clients/src after"
    )
    ap.add_argument("--seeds", type=int, nargs="+", default=[0, 1, 2])
    ap.add_argument("--threshold", type=float, default=0.75)
    ap.add_argument("--eval-interval", type=int, default=262_144)
    ap.add_argument("--cap", type=int, default=3_145_728, help="frames at most per run")
    ap.add_argument(
        "--set", nargs="*", default=[], help="more trainer settings, both codes"
    )
    ap.add_argument(
        "--after-set", nargs="*", default=[], help="settings of the after code only"
    )
    ap.add_argument(
        "--out", required=True, help="the JSON kept (results/time_to_driver/NAME.json)"
    )
    args = ap.parse_args()
    out = Path(args.out)
    done = json.loads(out.read_text()) if out.is_file() else {"runs": {}}
    recipe = RECIPE + [f"eval_interval={args.eval_interval}", *args.set]
    kept = (done.get("recipe", recipe), done.get("after_settings", args.after_set))
    if kept != (
        recipe,
        args.after_set,
    ):  # resuming: its runs must be of the same settings
        raise SystemExit(
            f"{out} keeps runs of other settings ({' '.join(kept[0])}; after: "
            f"{' '.join(kept[1]) or 'none'}): give the same ones, or another --out"
        )
    done["recipe"], done["after_settings"] = recipe, args.after_set
    # what "validation" is: the carve of the task's train scenes, named by its pool's content
    cfg = load_config(None, RECIPE)
    done["validation_pool"] = (
        validation_label(cfg.world.scenario_pool, cfg.world.validation_scenes) + ".json"
    )
    codes = {"before": args.before, "after": args.after}
    settings = {"before": args.set, "after": args.set + args.after_set}
    for i, seed in enumerate(args.seeds):
        for code in ("before", "after") if i % 2 == 0 else ("after", "before"):
            key = f"{code}-s{seed}"
            if key in done["runs"]:
                continue
            with tempfile.TemporaryDirectory() as tmp:
                run = one_run(codes[code], seed, args, Path(tmp), settings[code])
            done["runs"][key] = run
            out.parent.mkdir(parents=True, exist_ok=True)
            out.write_text(json.dumps(done, indent=1))
            print(
                f"{key}: {run['frames_to_threshold']} frames, "
                f"{run['minutes_to_threshold']} min (box {run['box_minutes']:.1f} min)",
                flush=True,
            )
    runs = {c: [done["runs"][f"{c}-s{s}"] for s in args.seeds] for c in codes}
    summary = {c: {"median_minutes": median_minutes(r)} for c, r in runs.items()}
    for c, r in runs.items():
        reached = [
            x["frames_to_threshold"] for x in r if x["frames_to_threshold"] is not None
        ]
        summary[c]["median_frames"] = statistics.median(
            x if x is not None else math.inf
            for x in (y["frames_to_threshold"] for y in r)
        )
        summary[c]["reached"] = len(reached)
    summary["ratio_minutes"] = (
        summary["after"]["median_minutes"] / summary["before"]["median_minutes"]
    )
    summary["per_frame"] = per_frame(runs["before"], runs["after"])
    done["summary"] = summary
    out.write_text(json.dumps(done, indent=1))
    print(json.dumps(summary, indent=1))


if __name__ == "__main__":
    main()
