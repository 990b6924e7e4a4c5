"""Test-success curves of training runs, against frames and wall time, as a markdown table.

Reads each run's ``metrics.csv`` (``python -m sharedspace.train``'s ``eval/*`` rows: the
deterministic policy on every test scene, curves only) and prints, per evaluation, each run's
success and collision with the training wall time so far (collection and updates;
``eval/train_wall_s``) and the run's wall time including its evaluations (the log's clock),
then when each run first reaches each of ``--marks`` and its last evaluation.

Usage: python benchmarks/learning_curves.py results/ppo/runs/crowd-scratch-gcn_cog-s* \
       [--marks pursuit_3=0.605 car_aware=0.908] [--budget-min 10]
"""

from __future__ import annotations

import argparse
import csv
import json
from pathlib import Path


def curve(run: Path) -> list[dict]:
    """One row per evaluation: frames, success, collision, train_min, wall_min."""
    rows: dict[int, dict] = {}
    with open(run / "metrics.csv") as f:
        for r in csv.DictReader(f):
            if not r["metric"].startswith("eval/"):
                continue
            row = rows.setdefault(int(r["frames"]), {"frames": int(r["frames"])})
            row["wall_min"] = float(r["wall_s"]) / 60
            key = r["metric"].removeprefix("eval/")
            if key in ("success", "collision", "timeout"):
                row[key] = float(r["value"])
            elif key == "train_wall_s":
                row["train_min"] = float(r["value"]) / 60
    return [rows[k] for k in sorted(rows)]


def first_reaching(rows: list[dict], level: float) -> dict | None:
    return next((r for r in rows if r["success"] >= level), None)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("runs", nargs="+", type=Path)
    ap.add_argument(
        "--marks", nargs="*", default=["pursuit_3=0.605", "car_aware=0.908"]
    )
    ap.add_argument(
        "--budget-min", type=float, default=10.0, help="training wall budget"
    )
    ap.add_argument("--json", default="", help="also write the curves here")
    args = ap.parse_args()
    curves = {run.name: curve(run) for run in args.runs}
    names = list(curves)
    print(
        "| frames | "
        + " | ".join(f"{n}: success / collision (train min)" for n in names)
        + " |"
    )
    print("|---:|" + "---|" * len(names))
    frames = sorted({r["frames"] for rows in curves.values() for r in rows})
    for fr in frames:
        cells = []
        for n in names:
            r = next((r for r in curves[n] if r["frames"] == fr), None)
            cells.append(
                f"{r['success']:.3f} / {r['collision']:.3f} ({r.get('train_min', 0):.1f})"
                if r
                else ""
            )
        print(f"| {fr:,} | " + " | ".join(cells) + " |")
    print()
    marks = [(m.split("=")[0], float(m.split("=")[1])) for m in args.marks]
    marks.append(("0.80", 0.80))
    for n, rows in curves.items():
        parts = []
        for label, level in marks:
            hit = first_reaching(rows, level)
            parts.append(
                f"{label} ({level:.3f}) at {hit['frames']:,} frames, {hit.get('train_min', 0):.1f} "
                f"train min ({hit['wall_min']:.1f} with evaluations)"
                if hit
                else f"{label}: never"
            )
        within = [r for r in rows if r.get("train_min", 0) <= args.budget_min]
        best_in_budget = within[-1] if within else None
        last = rows[-1] if rows else None
        print(f"- {n}: " + "; ".join(parts))
        if best_in_budget:
            print(
                f"  last evaluation within {args.budget_min:g} train min: "
                f"{best_in_budget['success']:.3f} at {best_in_budget['frames']:,} frames"
            )
        if last:
            print(
                f"  last evaluation (the run's policy): {last['success']:.3f} success, "
                f"{last['collision']:.3f} collision at {last['frames']:,} frames, "
                f"{last.get('train_min', 0):.1f} train min"
            )
    if args.json:
        Path(args.json).write_text(json.dumps(curves, indent=1))


if __name__ == "__main__":
    main()
