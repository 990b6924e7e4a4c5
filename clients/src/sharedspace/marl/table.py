"""The multi-car table: MAPPO, IPPO and MASAC, 3 seeds each, on the crossing task's test scenes,
against every car running the car-aware script (``make marl``).

Runs go two at a time (one per core of a 2-core box), each against its own local server; a run
whose ``eval.json`` exists is kept, one with a checkpoint resumes. Writes ``table.json`` and
``table.md`` (per-car success, collision and car-car collision with Wilson intervals pooled over
the seeds, the paired difference to the script by scene-bootstrap, wall time) and every run's
config, metrics and evaluation under ``--out`` (default results/marl).

    python -m sharedspace.marl.table [--out results/marl] [--seeds 3] [--parallel 2]
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import time
from collections.abc import Sequence
from pathlib import Path

from sharedspace.cli import run_command
from sharedspace.client import Connection
from sharedspace.local_server import LocalServer
from sharedspace.marl.evaluate import paired_difference, play, scripted_act, summarize
from sharedspace.marl.task import CrossingTask
from sharedspace.train.registry import algorithm_names

__all__ = ["main"]


def _run_dir(out: Path, algorithm: str, seed: int) -> Path:
    return out / "runs" / f"{algorithm}-seed{seed}"


def _launch(out: Path, algorithm: str, seed: int, sets: Sequence[str]) -> subprocess.Popen:
    log_dir = _run_dir(out, algorithm, seed)
    log_dir.mkdir(parents=True, exist_ok=True)
    cmd = [
        sys.executable, "-m", "sharedspace.marl", "--resume",
        "--set", f"algorithm={algorithm}", "--set", f"seed={seed}",
        "--set", f"log_dir={log_dir}",
    ]  # fmt: skip
    for s in sets:
        cmd += ["--set", s]
    return subprocess.Popen(cmd, stdout=open(log_dir / "stdout.log", "w"), stderr=subprocess.STDOUT)


def _markdown(table: dict) -> list[str]:
    """The table's rows in markdown."""
    lines = [
        "| drivers | per-car success [95 % CI] | collision | car-car "
        "| paired vs car_aware [95 % CI] |",
        "|---|---|---|---|---|",
    ]
    for name, entry in table.items():
        s = entry["summary"]
        pair = entry.get("paired_vs_car_aware")
        lines.append(
            f"| {name} | {s['success']['rate']:.3f} [{s['success']['ci95'][0]:.3f}, "
            f"{s['success']['ci95'][1]:.3f}] | {s['collision']['rate']:.3f} | "
            f"{s['car_collision']['rate']:.3f} | "
            + (
                f"{pair['mean']:+.3f} [{pair['ci95'][0]:+.3f}, {pair['ci95'][1]:+.3f}]"
                if pair
                else "—"
            )
            + " |"
        )
    return lines


def main(argv: Sequence[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="python -m sharedspace.marl.table", description=__doc__)
    ap.add_argument("--out", default="results/marl")
    ap.add_argument("--seeds", type=int, default=3)
    ap.add_argument("--parallel", type=int, default=2)
    ap.add_argument("--algorithms", default=",".join(algorithm_names("many")))
    ap.add_argument("--set", action="append", default=[], help="key=value for every run")
    args = ap.parse_args(argv)
    out = Path(args.out)
    task = CrossingTask()
    t0 = time.time()
    todo = [
        (a, s)
        for a in args.algorithms.split(",")
        for s in range(args.seeds)
        if not (_run_dir(out, a, s) / "eval.json").exists()
    ]
    running: list[tuple[subprocess.Popen, str, int]] = []
    while todo or running:
        while todo and len(running) < args.parallel:
            a, s = todo.pop(0)
            running.append((_launch(out, a, s, args.set), a, s))
        time.sleep(2)
        for item in list(running):
            if item[0].poll() is not None:
                running.remove(item)
                if item[0].returncode:
                    print(f"{item[1]} seed {item[2]} failed: see its stdout.log", file=sys.stderr)
                    return 1
    wall = time.time() - t0
    with LocalServer(prefix="marltable") as server:
        baseline = play(
            task,
            scripted_act("car_aware"),
            Connection(endpoint=server.endpoint, prefix="marltable"),
        )
    rows_by = {
        a: [json.loads((_run_dir(out, a, s) / "eval.json").read_text()) for s in range(args.seeds)]
        for a in args.algorithms.split(",")
    }
    table = {"car_aware": {"summary": summarize(baseline)}}
    for a, evals in rows_by.items():
        rows = [r for e in evals for r in e["rows"]]
        table[a] = {
            "summary": summarize(rows),
            "paired_vs_car_aware": paired_difference(rows, baseline),
            "per_seed_success": [e["summary"]["success"]["rate"] for e in evals],
            "run_wall_s": [e["summary"].get("wall_s") for e in evals],
        }
    report = {
        "date": time.strftime("%Y-%m-%d %H:%M UTC", time.gmtime()),
        "command": " ".join(["python -m sharedspace.marl.table", *(argv or sys.argv[1:])]),
        "task": {k: v for k, v in vars(task).items()},
        "wall_s_this_call": wall,
        "table": table,
        "baseline_rows": baseline,
    }
    (out / "table.json").write_text(json.dumps(report, indent=1))
    lines = _markdown(table)
    (out / "table.md").write_text("\n".join(lines) + "\n")
    print("\n".join(lines))
    print(f"wall time of this call: {wall / 60:.1f} min")
    return 0


if __name__ == "__main__":
    sys.exit(run_command(main))
