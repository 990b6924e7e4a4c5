"""K-fold cross-validation of Table I over every scenario of the paper pool (docs/RESULTS.md).

    python -m calibration.crossval --folds 5 --out out/crossval [--objective collisions]

The 59 / 18 split of the paper pool scores the models on 18 scenes. Here the 77 scenes are
dealt into K folds (scene i goes to fold i mod K, in pool order); for each fold the three
calibrated models (SFM, RA-SFM, CR-SFM) are fitted on the other K - 1 folds with
``calibration.calibrate`` (same objective and budget as the shipped calibration) and scored on
the held-out fold with ``sim-server eval-peds``. Every scene is scored exactly once, by
parameters that never saw it; the K held-out tables are merged into one (the models' ADE, FDE
and collision rate are means over the 77 scenes) and compared pairwise by
``calibration.paired``. Each fold's pool, parameters and scores stay in ``--out``; a fold
already there is not fitted again, so an interrupted run resumes.
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
from pathlib import Path

from sharedspace.models import EVALUATED_MODELS

from calibration.common import DEFAULT_SERVER, REPO

PAPER_POOL = REPO / "scenarios" / "data" / "hbs-paper.json"
MODELS = EVALUATED_MODELS


def fold_pool(pool: dict, folds: int, fold: int) -> dict:
    """``pool`` with scene i in the test split when ``i mod folds == fold``, else train."""
    scenes = [
        {**s, "split": "test" if i % folds == fold else "train"} for i, s in enumerate(pool["scenarios"])
    ]
    return {
        **pool,
        "name": f"{pool['name']}-fold{fold}of{folds}",
        "provenance": f"{pool['provenance']} | cross-validation fold {fold} of {folds}: scene i "
        f"is a test scene when i mod {folds} = {fold}",
        "scenarios": scenes,
    }


def merge(tables: list[dict]) -> dict:
    """One Table I from the held-out tables of the folds: per model every scene's record, and
    ADE, FDE, collision rate and early-arrival share as means over the scenes."""
    out = {"models": {}, "models_order": list(MODELS), "split": "cross-validated", "folds": []}
    for m in MODELS:
        scenes = [s for t in tables for s in t["models"][m]["scenarios"]]
        n = len(scenes)
        out["models"][m] = {
            "scenarios": scenes,
            "episodes": n,
            "ade": sum(s["ade"] for s in scenes) / n,
            "fde": sum(s["fde"] for s in scenes) / n,
            "collision_rate": sum(bool(s["collided"]) for s in scenes) / n,
        }
    return out


def run(cmd: list[str]) -> None:
    print("+", " ".join(cmd), file=sys.stderr, flush=True)
    subprocess.run(cmd, check=True)


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--server", type=Path, default=DEFAULT_SERVER)
    ap.add_argument("--folds", type=int, default=5)
    ap.add_argument("--out", type=Path, default=REPO / "out" / "crossval")
    ap.add_argument("--n-init", type=int, default=15, help="as calibration.calibrate")
    ap.add_argument("--n-iter", type=int, default=110, help="as calibration.calibrate")
    ap.add_argument("--objective", default="ade_fde", help="as calibration.calibrate")
    ap.add_argument("--collision-weight", type=float, default=2.0)
    ap.add_argument("--table", type=Path, default=None, help="write the merged table here")
    args = ap.parse_args(argv)
    if args.folds < 2:
        ap.error("--folds must be at least 2")

    args.out.mkdir(parents=True, exist_ok=True)
    pool = json.loads(PAPER_POOL.read_text())
    tables = []
    for f in range(args.folds):
        pool_file = args.out / f"fold{f}.json"
        params = args.out / f"fold{f}.json5"
        scores = args.out / f"fold{f}_test.json"
        pool_file.write_text(json.dumps(fold_pool(pool, args.folds, f)))
        if not params.is_file():
            run(
                [
                    sys.executable,
                    "-m",
                    "calibration.calibrate",
                    "--server",
                    str(args.server),
                    "--pool",
                    str(pool_file),
                    "--out",
                    str(params),
                    "--n-init",
                    str(args.n_init),
                    "--n-iter",
                    str(args.n_iter),
                    "--objective",
                    args.objective,
                    "--collision-weight",
                    str(args.collision_weight),
                ]
            )
        if not scores.is_file():
            run(
                [
                    str(args.server),
                    "eval-peds",
                    "--pool",
                    str(pool_file),
                    "--split",
                    "test",
                    "--params",
                    str(params),
                    "--out",
                    str(scores),
                ]
            )
        tables.append(json.loads(scores.read_text()))
    table = merge(tables)
    table["folds"] = args.folds
    table["budget"] = {"n_init": args.n_init, "n_iter": args.n_iter, "objective": args.objective}
    if args.objective == "collisions":
        table["budget"]["collision_weight"] = args.collision_weight
    target = args.table or args.out / "table1_crossval.json"
    target.write_text(json.dumps(table, indent=1))
    print(f"{target}: {table['models']['cr_sfm']['episodes']} scenes scored out of fold")


if __name__ == "__main__":
    main()
