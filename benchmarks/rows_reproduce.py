"""Every published learned row of the benchmark, scored again from its shipped policies and
compared episode by episode with its published result (``results/bench/TASK/ROW.json``): the
check that a change of the trainer's code moved nothing published.

A row's episodes are matched by (policy, scene, unit); an episode *differs* when its status or
its step count does. Prints a line per row (episodes, how many differ, the published and the
new success rate) and one JSON line; exits 1 when any row differs.

Usage: python benchmarks/rows_reproduce.py [--tasks paper crowd] [--rows ROW ...]
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

from sharedspace.bench.scoring import score

REPO = Path(__file__).resolve().parents[1]


def learned_rows(task: str, names: list[str]) -> list[Path]:
    """The published results of ``task`` whose policies are shipped checkpoints."""
    out = []
    for path in sorted((REPO / "results" / "bench" / task).glob("*.json")):
        doc = json.loads(path.read_text())
        if not isinstance(doc, dict) or "sources" not in doc:
            continue
        if all(s.get("kind") == "checkpoint" for s in doc["sources"]):
            if not names or doc["policy"] in names:
                out.append(path)
    return out


def _key(e: dict) -> tuple:
    return (e["policy"], e["scene"], e["unit"])


def compare(path: Path, task: str) -> dict:
    """Scores the row of ``path`` again; the count of its episodes that differ."""
    doc = json.loads(path.read_text())
    specs = [str(REPO / s["path"]) for s in doc["sources"]]
    t0 = time.perf_counter()
    again = score(task, specs, name=doc["policy"]).to_json()
    published = {_key(e): (e["status"], e["steps"]) for e in doc["episodes"]}
    new = {_key(e): (e["status"], e["steps"]) for e in again["episodes"]}
    differ = sum(published.get(k) != v for k, v in new.items()) + len(published.keys() - new)
    return {
        "task": task,
        "row": doc["policy"],
        "episodes": len(new),
        "differ": differ,
        "success_published": doc["summary"]["success"]["rate"],
        "success_now": again["summary"]["success"]["rate"],
        "wall_s": round(time.perf_counter() - t0, 1),
    }


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--tasks", nargs="*", default=["paper", "crowd"])
    ap.add_argument("--rows", nargs="*", default=[], help="only these rows (by name)")
    args = ap.parse_args()
    rows = []
    for task in args.tasks:
        for path in learned_rows(task, args.rows):
            row = compare(path, task)
            rows.append(row)
            print(
                f"{task} {row['row']}: {row['episodes']} episodes, {row['differ']} differ; "
                f"success {row['success_published']:.4f} -> {row['success_now']:.4f} "
                f"({row['wall_s']} s)",
                flush=True,
            )
    print(json.dumps(rows))
    return 1 if any(r["differ"] for r in rows) else 0


if __name__ == "__main__":
    sys.exit(main())
