"""Training pools beyond the paper's 59 scenes, with the paper's test split kept unseen, and a
validation pool carved from the training scenes.

    python -m sharedspace.paper.pools --general general.json --out paper-plus-general.json
    python -m sharedspace.paper.pools --validation 12 --out paper-validation.json

Table II's learners reach 0.99 success on their 59 training scenes and 0.83 on the 18 test
scenes (docs/RESULTS.md, "Reading Table II"): they overfit. :func:`paper_plus_general` builds a
larger training pool from the same recording: the paper pool's train scenes plus every scene of
the general pool (every pedestrian of a car's window, scenarios/EXTRACTION.md) that shares **no
recorded agent** with any paper test scene, so no test pedestrian's or car's track is ever
trained on. Its test split is exactly the paper's test split, so test figures stay comparable
with Table II. ``scripts/table2.sh`` builds it when ``TABLE2_POOL=paper+general``.

:func:`validation_pool` is for choosing what to keep (a checkpoint, a setting) without looking
at the test split: ``n`` of the paper's train scenes, drawn by a fixed seed, become its ``test``
split (the validation scenes) and the paper's test scenes leave the pool. Trained on its train
split and scored on its test split, a run never sees the paper's test scenes. Like the paper's
own split, a validation scene may share a recorded pedestrian with a train scene (13 of the 59
train scenes share one with a test scene).
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path
from typing import Any

from sharedspace import worlds
from sharedspace.cli import run_command
from sharedspace.pool import DEFAULT_POOL_PATH

__all__ = ["paper_plus_general", "record_ids", "validation_pool"]


def record_ids(scenario: dict[str, Any]) -> set[int]:
    """The recorded agents (HBS track ids) a scenario replays or simulates."""
    return {int(a["record_id"]) for a in scenario["agents"]}


def paper_plus_general(
    paper: dict[str, Any], general: dict[str, Any], name: str = "hbs-paper-plus-general"
) -> dict[str, Any]:
    """A pool file (scenarios/FORMAT.md): ``paper``'s scenes with their splits, then the scenes
    of ``general`` that share no record id with a test scene of ``paper``, renamed
    ``general-<name>`` and put in the train split."""
    test = [s for s in paper["scenarios"] if s["split"] == "test"]
    held_out = set().union(*(record_ids(s) for s in test)) if test else set()
    extra = []
    for s in general["scenarios"]:
        if record_ids(s) & held_out:
            continue
        extra.append({**s, "name": f"general-{s['name']}", "split": "train"})
    return {
        "version": paper["version"],
        "name": name,
        "provenance": (
            f"{paper['name']} (train and test splits as extracted) plus the {len(extra)} "
            f"scenes of {general['name']} that share no recorded agent with a {paper['name']} "
            "test scene, all in the train split (sharedspace.paper.pools.paper_plus_general)"
        ),
        "scenarios": list(paper["scenarios"]) + extra,
    }


def validation_pool(
    paper: dict[str, Any], n: int, seed: int = 0, name: str | None = None
) -> dict[str, Any]:
    """The trainer's validation pool (:func:`sharedspace.worlds.validation_pool`: ``n`` of
    ``paper``'s train scenes, chosen by ``seed``, as the ``test`` split; its test scenes left
    out; its vehicle model kept), named ``<paper's name>-validation`` unless ``name``."""
    return worlds.validation_pool(paper, n, seed) | {"name": name or f"{paper['name']}-validation"}


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    what = ap.add_mutually_exclusive_group(required=True)
    what.add_argument("--general", help="the general pool file (extract-hbs --pool general)")
    what.add_argument(
        "--validation", type=int, metavar="N", help="N train scenes as the validation split"
    )
    ap.add_argument("--seed", type=int, default=0, help="seed of the validation scenes' draw")
    ap.add_argument("--paper", default=str(DEFAULT_POOL_PATH), help="the paper pool file")
    ap.add_argument("--out", required=True, help="where to write the pool")
    args = ap.parse_args(argv)
    paper = json.loads(Path(args.paper).read_text())
    if args.validation is not None:
        pool = validation_pool(paper, args.validation, args.seed)
    else:
        pool = paper_plus_general(paper, json.loads(Path(args.general).read_text()))
    Path(args.out).write_text(json.dumps(pool))
    splits = [s["split"] for s in pool["scenarios"]]
    print(
        f"{args.out}: {len(splits)} scenes ({splits.count('train')} train, "
        f"{splits.count('test')} test)"
    )


if __name__ == "__main__":
    sys.exit(run_command(main))
