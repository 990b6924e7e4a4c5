"""Training pools beyond the paper's 59 scenes, with the paper's test split kept unseen.

    python -m sharedspace.train.pools --general general.json --out paper-plus-general.json

Table II's learners reach 0.99 success on their 59 training scenes and 0.83 on the 18 test
scenes (docs/RESULTS.md, "Reading Table II"): they overfit. :func:`paper_plus_general` builds a
larger training pool from the same recording: the paper pool's train scenes plus every scene of
the general pool (every pedestrian of a car's window, scenarios/EXTRACTION.md) that shares **no
recorded agent** with any paper test scene, so no test pedestrian's or car's track is ever
trained on. Its test split is exactly the paper's test split, so test figures stay comparable
with Table II. ``scripts/table2.sh`` builds it when ``TABLE2_POOL=paper+general``.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path
from typing import Any

from sharedspace.pool import DEFAULT_POOL_PATH

__all__ = ["paper_plus_general", "record_ids"]


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
            "test scene, all in the train split (sharedspace.train.pools.paper_plus_general)"
        ),
        "scenarios": list(paper["scenarios"]) + extra,
    }


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument(
        "--general", required=True, help="the general pool file (extract-hbs --pool general)"
    )
    ap.add_argument("--paper", default=str(DEFAULT_POOL_PATH), help="the paper pool file")
    ap.add_argument("--out", required=True, help="where to write the combined pool")
    args = ap.parse_args(argv)
    pool = paper_plus_general(
        json.loads(Path(args.paper).read_text()), json.loads(Path(args.general).read_text())
    )
    Path(args.out).write_text(json.dumps(pool))
    splits = [s["split"] for s in pool["scenarios"]]
    print(
        f"{args.out}: {len(splits)} scenes ({splits.count('train')} train, "
        f"{splits.count('test')} test)"
    )


if __name__ == "__main__":
    main()
