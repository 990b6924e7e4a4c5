"""A task's leaderboard from its result files: one row per result, best success first, each
with its Wilson intervals, its paired difference against the task's ``car_aware`` row, and for a
learned row its success on the validation split, on which the task's best row is chosen
(:mod:`sharedspace.arms.best`, ``OUT/best.json``): the table says which, and the test scores
above it play no part in that choice.

    python -m sharedspace.bench.leaderboard results/bench/crowd [--out LEADERBOARD.md]
"""

from __future__ import annotations

import argparse
import json
import sys
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from sharedspace.bench.scoring import Result, compare, load_result
from sharedspace.bench.tasks import REPO, BenchError
from sharedspace.cli import run_command
from sharedspace.outcomes import STATUSES

__all__ = ["legend", "render"]

#: What the rates are, under every table the bench prints.
RATES = (
    "success, collision, timeout: the shares of the task's episodes in which the car reached its "
    "goal, collided, or ran out of time (they add up to 1); [95 %]: the Wilson interval over "
    "those episodes."
)
#: The rows that give a score its scale: the floor (a car that does nothing: it keeps its
#: initial speed and heading, action [0, 0]) and the car-aware script.
SCALE_ROWS = (
    ("hold", "floor: does nothing, keeps its speed and heading"),
    ("car_aware", "the car-aware script"),
)


def legend(task: dict[str, Any], folder: Path | None = None) -> str:
    """The bench's legend for ``task`` (a result's task record): what the rates are, and the
    task's floor and script success from the shipped results (``results/bench/TASK``, where
    they are, at the same task version)."""
    folder = folder or REPO / "results" / "bench" / task["name"]
    scale = []
    for name, what in SCALE_ROWS:
        path = folder / f"{name}.json"
        if not path.is_file():
            continue
        row = load_result(path)
        if row.task.get("version") == task.get("version"):
            scale.append(f"`{name}` ({what}) {row.summary['success']['rate']:.3f}")
    text = RATES
    if scale:
        text += f" Success on `{task['name']}@{task['version']}` for scale: " + "; ".join(scale)
        text += "."
    return text + "\n"


def render(
    results: Sequence[Result], reference: str = "car_aware", best: dict[str, Any] | None = None
) -> str:
    """The markdown table of ``results`` (all of one task version); ``best``: the task's entry
    of ``best.json`` (its ``name`` and every row's ``validation`` score), if there is one."""
    validation = (best or {}).get("validation", {})
    ref = next((r for r in results if r.policy == reference), None)
    task = results[0].task
    lines = [
        f"Task `{task['name']}@{task['version']}` ({task['description']}; fingerprint "
        f"{task['fingerprint']}). Paired differences: scenes resampled, 95 %"
        + ("; scenes fixed in brackets after it." if task.get("scenes_fixed_interval") else "."),
        "",
        f"| row | seeds | episodes | success [95 %] | collision | timeout | − {reference} "
        "| validation success |",
        "|---|---:|---:|---|---:|---:|---|---:|",
    ]
    for r in sorted(results, key=lambda r: -r.summary["success"]["rate"]):
        s = r.summary
        cell = "–"
        if ref is not None and r is not ref:
            c = compare(r, ref)
            cell = f"{c['diff']:+.3f} [{c['lo']:+.3f}, {c['hi']:+.3f}]"
            if "lo_fixed" in c:
                cell += f" [{c['lo_fixed']:+.3f}, {c['hi_fixed']:+.3f}]"
        success = s["success"]
        lines.append(
            f"| {r.policy} | {len(r.sources)} | {s['episodes']} | {success['rate']:.3f} "
            f"[{success['ci95'][0]:.3f}, {success['ci95'][1]:.3f}] | "
            + " | ".join(f"{s[k]['rate']:.3f}" for k in STATUSES[1:])
            + f" | {cell} | {_validation_cell(validation.get(r.policy))} |"
        )
    if best:
        lines += [
            "",
            f"Best learned row, chosen on validation: **{best['name']}** (validation: "
            "the train scenes carved off for it, never the test scenes; * = a row whose runs "
            "trained on those scenes too).",
        ]
    return "\n".join(lines) + "\n\n" + RATES + "\n"


def _validation_cell(v: dict[str, Any] | None) -> str:
    if v is None:
        return "–"
    return f"{v['success']:.3f}" + ("" if v.get("held_out", True) else "*")


def main(argv: Sequence[str] | None = None) -> int:
    ap = argparse.ArgumentParser(
        prog="python -m sharedspace.bench.leaderboard", description=__doc__
    )
    ap.add_argument("folder", help="a task's results folder (OUT/TASK of the bench)")
    ap.add_argument("--out", default="", help="also write the table to this file")
    args = ap.parse_args(argv)
    results = []
    for path in sorted(Path(args.folder).glob("*.json")):
        try:  # the folder also keeps the runs' wall times and the paired questions
            results.append(load_result(path))
        except BenchError:
            continue
    folder = Path(args.folder)
    best_file = folder.parent / "best.json"
    task = results[0].task["name"] if results else ""
    best = json.loads(best_file.read_text()).get(task) if best_file.is_file() else None
    text = render(results, best=best)
    print(text)
    if args.out:
        Path(args.out).write_text(text)
    return 0


if __name__ == "__main__":
    sys.exit(run_command(main))
