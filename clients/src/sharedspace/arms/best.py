"""Each task's best learned row, chosen on validation: never on the test scenes.

    python -m sharedspace.arms.best paper crowd [--out results/bench]

A row is the seeds of one arm and network (``OUT/policies/TASK-ARM-NETWORK-sSEED.pt``, what
:mod:`sharedspace.arms.rows` ships). Every shipped policy is scored once on its task's
validation split, the train scenes the trainer carves off (:mod:`sharedspace.worlds`), at
:data:`VALIDATION_EPISODES` episodes or more, as the scratch runs' own last scoring is; the
scores are kept in ``OUT/TASK/validation.json``. The row whose seeds score the highest pooled
success there (fewer collisions break a tie) is the task's best, written to
``OUT/best.json`` (what ``make run`` scores on the test scenes) with every row's validation
score beside it; the leaderboards show the same column. A row whose runs date from before the
validation split (the residual arm of 2026-12-06, its curves drawn on the test scenes) trained
on those scenes too: its score is marked ``held_out: false``, an optimistic one.
"""

from __future__ import annotations

import argparse
import hashlib
import json
import re
import sys
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from sharedspace.cli import run_command
from sharedspace.train.checkpoint import read_checkpoint
from sharedspace.train.evaluation import evaluate_split
from sharedspace.train.learners import load_checkpoint_actor
from sharedspace.worlds import TRAINING_TASKS

__all__ = ["VALIDATION_EPISODES", "choose_best", "validation_scores"]

#: Validation episodes per scoring, at least: one scoring's standard error near 0.012 at 0.85.
VALIDATION_EPISODES = 960
#: How best.json says what the best row was chosen on.
CHOSEN_ON = (
    "the validation split (train scenes carved off by sharedspace.worlds, never the test "
    "scenes): each seed's shipped last checkpoint scored there, pooled over the row's seeds"
)


def validation_variations(task: str) -> int:
    """Variations per validation scene that make :data:`VALIDATION_EPISODES` episodes."""
    return -(-VALIDATION_EPISODES // TRAINING_TASKS[task].validation_scenes)


def score_on_validation(policy: Path, task: str) -> dict[str, Any]:
    """``policy`` (a single-car checkpoint trained for ``task``) played on the task's
    validation split with the deterministic policy: success, collision, timeout, episodes, and
    ``held_out``: whether its run trained without those scenes (runs from before the split,
    whose curves were drawn on the test scenes, trained on every train scene)."""
    ckpt = read_checkpoint(policy)
    held_out = ckpt["config"].get("eval_split", "test") == "validation"
    cfg, actor = load_checkpoint_actor(
        ckpt,
        [
            "eval_split=validation",
            f"validation_scenes={TRAINING_TASKS[task].validation_scenes}",
            f"validation_variations={validation_variations(task)}",
            "server_endpoint=",
            "zenoh_config=",
        ],
    )
    summary = evaluate_split(cfg.world, actor, "validation", driving=cfg.driving)["summary"]
    return {k: summary[k] for k in ("episodes", "success", "collision", "timeout")} | {
        "held_out": held_out
    }


def _rows(task: str, out: Path) -> dict[str, list[Path]]:
    """Row name (``ARM-NETWORK``) -> its seeds' shipped policies."""
    rows: dict[str, list[Path]] = {}
    pattern = re.compile(rf"^{re.escape(task)}-(.+)-s\d+$")
    for path in sorted((out / "policies").glob(f"{task}-*.pt")):
        m = pattern.match(path.stem)
        if m:
            rows.setdefault(m.group(1), []).append(path)
    return rows


def validation_scores(task: str, out: Path) -> dict[str, dict[str, Any]]:
    """Every row of ``task``: its seeds' validation scores and their pooled success and
    collision. Scores already in ``OUT/TASK/validation.json`` (by policy name and content) are
    kept; the others are played now and added."""
    path = out / task / "validation.json"
    cache: dict[str, Any] = json.loads(path.read_text()) if path.is_file() else {}
    rows = {}
    for row, policies in _rows(task, out).items():
        seeds = []
        for policy in policies:
            key = f"{policy.name}:{hashlib.sha256(policy.read_bytes()).hexdigest()[:16]}"
            if key not in cache:
                cache[key] = score_on_validation(policy, task)
                path.parent.mkdir(parents=True, exist_ok=True)
                path.write_text(json.dumps(cache, indent=1, sort_keys=True))
            seeds.append({"policy": str(policy), **cache[key]})
        rows[row] = {
            "seeds": seeds,
            "held_out": all(s["held_out"] for s in seeds),
            "success": sum(s["success"] for s in seeds) / len(seeds),
            "collision": sum(s["collision"] for s in seeds) / len(seeds),
        }
    return rows


def choose_best(tasks: Sequence[str], out: Path, min_seeds: int = 3) -> dict[str, Any]:
    """Writes ``OUT/best.json``: each task's row of the highest pooled validation success among
    those with ``min_seeds`` seeds or more; returns its content."""
    best: dict[str, Any] = {
        "about": "The best learned row of each task's leaderboard (docs/RESULTS.md, "
        "Leaderboards): what `make run` scores with the bench. A row is its seeds pooled; "
        "their policies are the runs' last checkpoints.",
        "chosen_on": CHOSEN_ON,
    }
    path = out / "best.json"
    if path.is_file():  # the tasks not asked about now keep their entries
        best = {**json.loads(path.read_text()), **best}
    for task in tasks:
        rows = {
            r: v for r, v in validation_scores(task, out).items() if len(v["seeds"]) >= min_seeds
        }
        if not rows:
            continue
        name = max(rows, key=lambda r: (rows[r]["success"], -rows[r]["collision"]))
        best[task] = {
            "name": name,
            "policies": [s["policy"] for s in rows[name]["seeds"]],
            "validation": {
                r: {
                    "success": round(v["success"], 4),
                    "collision": round(v["collision"], 4),
                    "held_out": v["held_out"],
                }
                for r, v in sorted(rows.items(), key=lambda kv: -kv[1]["success"])
            },
        }
    path.write_text(json.dumps(best, indent=1) + "\n")
    return best


def main(argv: Sequence[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="python -m sharedspace.arms.best", description=__doc__)
    ap.add_argument(
        "tasks", nargs="+", choices=[t for t, w in TRAINING_TASKS.items() if w.cars == 1]
    )
    ap.add_argument("--out", default="results/bench")
    args = ap.parse_args(argv)
    best = choose_best(args.tasks, Path(args.out))
    for task in args.tasks:
        if task in best:
            print(f"{task}: {best[task]['name']}")
            for row, v in best[task]["validation"].items():
                held = "" if v["held_out"] else " (scenes it trained on)"
                print(f"  {row}: success {v['success']:.3f}, collision {v['collision']:.3f}{held}")
    return 0


if __name__ == "__main__":
    sys.exit(run_command(main))
