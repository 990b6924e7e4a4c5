"""Table II-G's recipe against the rows played in other runs, paired on the same episodes.

1. The powered test of the shipped policies (``results/table2g/powered.json``) against the
   BC-script rows of the pilot (``results/prior/table2g_pilot_powered.json``): both played
   variation ``j`` (seed ``j``) of every test scene with the same variation spec, so the
   episodes pair (the car-aware script, played in both, gives the same outcomes: checked).
2. The ablation arms (``make table2g`` with ``TABLE2G_EXTRA``, results/prior/ablation_*.json)
   against the recipe's seeds 0 and 1 (results/table2g/table2g.json) on the deterministic 76 test
   scenes: a variant's outcome per scene is the mean over its seeds, clustered by scene.

Usage: python benchmarks/table2g_compare.py [--json results/table2g/compare.json]
Prints markdown tables.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

from sharedspace.paper.powered import comparisons, group_table

ROOT = Path(__file__).resolve().parents[1]


def load(path: str) -> dict:
    return json.loads((ROOT / path).read_text())


def deterministic_runs(path: str, seeds: list[str]) -> dict[str, list[dict]]:
    """A table2 JSON's G-SAC-Cog runs as powered-style episodes (variation 0 of each scene)."""
    per_run = load(path)["per_run"]["g_sac_cog"]
    return {
        f"s{s}": [{**e, "variation": 0} for e in per_run[s]["episodes"]] for s in seeds
    }


def row(c: dict, status: str = "success") -> str:
    x = c[status]
    return f"{x['diff']:+.3f} [{x['lo']:+.3f}, {x['hi']:+.3f}]"


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--json", default="results/table2g/compare.json")
    args = ap.parse_args()

    powered = load("results/table2g/powered.json")["episodes"]
    pilot = load("results/prior/table2g_pilot_powered.json")["episodes"]
    same = powered["car_aware"]["car_aware"] == pilot["car_aware"]["car_aware"]
    assert same, "the car-aware script's episodes differ: the two runs do not pair"
    groups = {**powered, "bc_script": pilot["bc_script"], "rlpd_bc": pilot["rlpd_bc"]}
    pairs = [
        (v, b)
        for v in ("g_sac_cog", "g_sac_nocog", "s_sac")
        for b in ("car_aware", "bc_script", "rlpd_bc")
    ]
    powered_rows = comparisons(groups, pairs)
    table = group_table({k: groups[k] for k in ("bc_script", "rlpd_bc")})
    print(
        "| A − B (powered, 304 episodes per run) | success diff [95 %, scenes resampled] | collision diff |"
    )
    print("|---|---|---|")
    for c in powered_rows:
        print(f"| {c['a']} − {c['b']} | {row(c)} | {row(c, 'collision')} |")
    for name, t in table.items():
        print(f"{name}: success {t['success']:.3f}, collision {t['collision']:.3f}")

    recipe = deterministic_runs("results/table2g/table2g.json", ["0", "1"])
    arms = {
        "recipe": recipe,
        "recipe + prior data": deterministic_runs(
            "results/prior/ablation_prior.json", ["0", "1"]
        ),
        "recipe, bc_weight 0": deterministic_runs(
            "results/prior/ablation_nobc.json", ["0", "1"]
        ),
    }
    arm_rows = comparisons(arms, [(a, "recipe") for a in arms if a != "recipe"])
    arm_table = group_table(arms)
    print()
    print(
        "| arm (G-SAC-Cog, seeds 0 and 1) | success | collision | − recipe, success [95 %] |"
    )
    print("|---|---:|---:|---|")
    for name, t in arm_table.items():
        diff = next((row(c) for c in arm_rows if c["a"] == name), "—")
        print(f"| {name} | {t['success']:.3f} | {t['collision']:.3f} | {diff} |")
    (ROOT / args.json).write_text(
        json.dumps(
            {
                "powered": powered_rows,
                "pilot_rows": table,
                "ablation": arm_rows,
                "ablation_table": arm_table,
            },
            indent=1,
        )
    )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
