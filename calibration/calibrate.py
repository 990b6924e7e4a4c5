"""Bayesian optimisation of the pedestrian models' parameters (paper section V, model.md section 9).

Each model (sfm, ra_sfm, cr_sfm) is fitted on the TRAIN split only; the objective is ADE + FDE
(metres, means over the train episodes) as computed by ``sim-server eval-peds`` (the paper's), or
with ``--objective collisions`` ADE + FDE + w * CR, where CR is the share of train episodes in
which a simulated pedestrian collides and w (``--collision-weight``, default 2 m) prices a
collision in every episode like 2 m of ADE + FDE. The surrogate is
the Gaussian process of the ``bayesian-optimization`` package (Matern 5/2 kernel, expected
improvement); scale parameters are searched in log10. The test split is never evaluated here.

Output: a JSON5 parameter file (default ``params/calibrated.json5``) that ``sim-server`` reads with
``--params``: every model's social-force parameters under ``pedestrians.<model>``, each risk-based
model's own ``gamma1``/``gamma2`` under ``models.<model>.risk`` (applied when that model drives the
pedestrians), and CR-SFM's as the world's ``risk`` values. Provenance is written as comments in the
file and as JSON beside it (``<out stem>.provenance.json``, with every evaluation's objective).

Usage (from the repository root)::

    python -m calibration.calibrate [--n-iter 110] [--n-init 15] [--seed 7]
        [--objective ade_fde|collisions] [--collision-weight 2.0] [--out params/calibrated.json5]
"""

from __future__ import annotations

import argparse
import datetime as dt
import json
import os
import platform
import sys
import time
from importlib.metadata import version
from pathlib import Path

import numpy as np
from bayes_opt import BayesianOptimization, acquisition

from calibration.common import (
    DEFAULT_SERVER,
    REPO,
    SPACES,
    STARTING_VALUES,
    BatchEvaluator,
    params_doc,
    run_json,
)

OBJECTIVES = ("ade_fde", "collisions")


def objective_of(result: dict, objective: str, collision_weight: float) -> float:
    """The calibration objective of one ``eval-peds`` result (see the module docs)."""
    value = result["ade"] + result["fde"]
    if objective == "collisions":
        value += collision_weight * result["collision_rate"]
    return value


def describe(objective: str, collision_weight: float) -> str:
    if objective == "collisions":
        return (
            f"ADE + FDE + {collision_weight:g} m x collision rate, means over the train-split "
            "episodes"
        )
    return "ADE + FDE (m), mean over the train-split episodes"


def calibrate_model(
    server: Path,
    model: str,
    pool: Path | None,
    n_init: int,
    n_iter: int,
    seed: int,
    objective: str = "ade_fde",
    collision_weight: float = 2.0,
) -> dict:
    """Runs the optimisation of one model; returns its best values and the run's record."""
    space = SPACES[model]
    pbounds = {p.name: p.bounds() for p in space}
    optimizer = BayesianOptimization(
        f=None,
        pbounds=pbounds,
        acquisition_function=acquisition.ExpectedImprovement(xi=0.01, random_state=seed),
        random_state=seed,
        verbose=0,
        allow_duplicate_points=True,
    )
    rng = np.random.RandomState(seed)
    history: list[float] = []
    best = (float("inf"), None)
    start = time.monotonic()
    with BatchEvaluator(server, "train", [model], pool=pool) as evaluate:

        def run(x: dict[str, float]) -> float:
            nonlocal best
            values = {p.name: p.decode(float(x[p.name])) for p in space}
            result = evaluate(params_doc(model, values))[model]
            obj = objective_of(result, objective, collision_weight)
            history.append(obj)
            if obj < best[0]:
                best = (obj, {"values": values, "train": result})
            optimizer.register(params=x, target=-obj)
            return obj

        # The model.md starting values first, then random points, then the GP-guided search.
        run({p.name: p.encode(STARTING_VALUES[p.name]) for p in space})
        for _ in range(n_init - 1):
            run({p.name: rng.uniform(*pbounds[p.name]) for p in space})
        for k in range(n_iter):
            run(optimizer.suggest())
            if (k + 1) % 20 == 0:
                print(
                    f"  {model}: {k + 1}/{n_iter} iterations, best {best[0]:.4f}, "
                    f"{time.monotonic() - start:.0f} s",
                    file=sys.stderr,
                    flush=True,
                )
        evaluations = evaluate.evaluations
    wall = time.monotonic() - start
    obj, rec = best
    return {
        "model": model,
        "values": rec["values"],
        "best_objective": obj,
        "best_train": rec["train"],
        "starting_objective": history[0],
        "evaluations": evaluations,
        "n_init": n_init,
        "n_iter": n_iter,
        "wall_s": wall,
        "history": history,
    }


def rounded(v: float) -> float:
    return float(f"{v:.5g}")


def format_json5(results: dict[str, dict], provenance: dict) -> str:
    """The commented parameter file."""
    lines = [
        "// Calibrated pedestrian-model parameters (paper Table I; docs/RESULTS.md).",
        "// Written by `python -m calibration.calibrate`; do not edit by hand:",
        "// re-run `make table1 CALIBRATE=1`.",
        f"// Data: pool `{provenance['pool']['name']}`, split `{provenance['split']}` only "
        f"({provenance['train_episodes']} episodes); the test split was never evaluated.",
        f"// Pool provenance: {provenance['pool']['provenance'][:300].replace(chr(10), ' ')}",
        f"// Objective: {provenance['objective']}.",
        f"// Optimiser: {provenance['library']} (GP surrogate, Matern 5/2, expected improvement xi=0.01),",
        f"//   seed {provenance['seed']}; scale parameters (tau, A, B, gamma2) searched in log10.",
        f"// Date: {provenance['date']}; machine: {provenance['machine']}; "
        f"total wall time {provenance['wall_s']:.0f} s.",
    ]
    for m, r in results.items():
        lines.append(
            f"// {m}: {r['evaluations']} evaluations ({r['n_init']} initial incl. the model.md starting "
            f"values, {r['n_iter']} GP-guided), train objective {r['starting_objective']:.4f} -> "
            f"{r['best_objective']:.4f} (as written, 5 significant digits: {r['written_objective']:.4f})."
        )
    lines += [
        "// Cognition (s0, q, s_o) is not calibrated: model.md section 3 defaults.",
        "// `models.<model>` overlays apply when that model drives the pedestrians",
        "// (sim-server/src/params_file.rs);",
        "// the world's `risk` (used by mixed worlds and the AV's risk graph) is CR-SFM's.",
        "{",
        "  pedestrians: {",
    ]
    for m, r in results.items():
        force = {p.name: rounded(r["values"][p.name]) for p in SPACES[m] if p.section == "force"}
        lines.append(f"    {m}: {json.dumps(force)},")
    lines.append("  },")
    risk = {
        m: {p.name: rounded(r["values"][p.name]) for p in SPACES[m] if p.section == "risk"}
        for m, r in results.items()
    }
    risk = {m: v for m, v in risk.items() if v}
    if "cr_sfm" in risk:
        lines.append(f"  risk: {json.dumps(risk['cr_sfm'])},")
    if risk:
        lines.append("  models: {")
        for m, v in risk.items():
            lines.append(f"    {m}: {{risk: {json.dumps(v)}}},")
        lines.append("  },")
    lines.append("}")
    return "\n".join(lines) + "\n"


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--server", type=Path, default=DEFAULT_SERVER)
    ap.add_argument("--pool", type=Path, default=None, help="pool file; the embedded pool if absent")
    ap.add_argument("--models", default=",".join(SPACES))
    ap.add_argument("--n-init", type=int, default=15, help="initial points per model (incl. defaults)")
    ap.add_argument("--n-iter", type=int, default=110, help="GP-guided iterations per model")
    ap.add_argument("--seed", type=int, default=7)
    ap.add_argument("--out", type=Path, default=REPO / "params" / "calibrated.json5")
    ap.add_argument("--date", default=None, help="date to record (default: today, ISO)")
    ap.add_argument("--machine", default=None, help="machine description to record")
    ap.add_argument(
        "--objective",
        choices=OBJECTIVES,
        default="ade_fde",
        help="ade_fde (the paper's) or collisions (ADE + FDE + w x collision rate)",
    )
    ap.add_argument(
        "--collision-weight", type=float, default=2.0, help="w of --objective collisions, m"
    )
    args = ap.parse_args()

    models = [m.strip() for m in args.models.split(",") if m.strip()]
    for m in models:
        if m not in SPACES:
            ap.error(f"--models: `{m}` has no parameters to calibrate ({', '.join(SPACES)})")
    pool_cmd = ["--pool", str(args.pool)] if args.pool else []
    info = run_json([str(args.server), "eval-peds", "--split", "train", "--models", "cv", *pool_cmd])
    train_episodes = info["models"]["cv"]["episodes"]

    started = time.monotonic()
    results: dict[str, dict] = {}
    for m in models:
        print(
            f"calibrating {m} ({len(SPACES[m])} parameters) on the train split ...",
            file=sys.stderr,
            flush=True,
        )
        results[m] = calibrate_model(
            args.server,
            m,
            args.pool,
            args.n_init,
            args.n_iter,
            args.seed,
            args.objective,
            args.collision_weight,
        )
        print(
            f"  {m}: best train objective {results[m]['best_objective']:.4f} after "
            f"{results[m]['evaluations']} evaluations, {results[m]['wall_s']:.0f} s",
            file=sys.stderr,
            flush=True,
        )
    wall = time.monotonic() - started

    # The objective with the values as written (rounded), for the record.
    with BatchEvaluator(args.server, "train", models, pool=args.pool) as evaluate:
        for m, r in results.items():
            written = {k: rounded(v) for k, v in r["values"].items()}
            res = evaluate(params_doc(m, written))[m]
            r["written_objective"] = objective_of(res, args.objective, args.collision_weight)

    provenance = {
        "pool": info["pool"],
        "split": "train",
        "train_episodes": train_episodes,
        "objective": describe(args.objective, args.collision_weight),
        "library": f"bayesian-optimization {version('bayesian-optimization')} "
        f"(scikit-learn {version('scikit-learn')}, numpy {version('numpy')})",
        "seed": args.seed,
        "date": args.date or dt.date.today().isoformat(),
        "machine": args.machine or f"{os.cpu_count()} cores, {platform.machine()} {platform.system()}",
        "python": platform.python_version(),
        "wall_s": wall,
        "models": {m: {k: v for k, v in r.items() if k != "model"} for m, r in results.items()},
    }
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(format_json5(results, provenance))
    side = args.out.with_name(args.out.name.split(".")[0] + ".provenance.json")
    side.write_text(json.dumps(provenance, indent=1) + "\n")
    print(f"wrote {args.out} and {side} ({wall:.0f} s)", file=sys.stderr)


if __name__ == "__main__":
    main()
