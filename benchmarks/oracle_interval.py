"""How good must a driver be for the scene-clustered 95 % interval of its paired difference from
the best script to clear 0 on the 18 paper test scenes? (issue 30's target)

    .venv/bin/python benchmarks/oracle_interval.py

The oracle succeeds in every varied scene the open-loop planner solved (variations 0..31,
results/variations/baseline.json: 563 of 576, success 0.977); the degraded oracles fail a
further fraction p of episodes at random. Each is paired with pursuit_5 and pursuit_3 on the same
episodes and the interval computed by sharedspace.stats.paired_clustered (scenes resampled).
"""

import json
import random
from pathlib import Path

from sharedspace.stats import paired_clustered

ROOT = Path(__file__).resolve().parents[2]
base = json.loads((ROOT / "results/variations/baseline.json").read_text())
names = [
    s["name"]
    for s in json.loads((ROOT / "scenarios/data/hbs-paper.json").read_text())[
        "scenarios"
    ]
]
unsolved = set(base["planner"]["unsolved"])
print(
    "| script | failures added p | success | 95 % interval, scenes resampled (5 draws of the failures) |"
)
print("|---|---:|---:|---|")
for script in ("pursuit_5", "pursuit_3"):
    oracle, other = {}, {}
    for r in base["episodes"][script][script]:
        if r["variation"] < 32:
            key = (r["scenario_index"], r["variation"])
            other[key] = float(r["status"] == "success")
            oracle[key] = (
                0.0
                if f"{names[r['scenario_index']]}#{r['variation']}" in unsolved
                else 1.0
            )
    for p in (0.0, 0.02, 0.04, 0.06):
        rng = random.Random(1)
        cis = []
        for rep in range(5):
            a = {k: (v if rng.random() >= p else 0.0) for k, v in oracle.items()}
            c = paired_clustered(a, other, resamples=4000, seed=rep)
            cis.append(f"[{c['lo']:+.3f}, {c['hi']:+.3f}]")
        print(
            f"| {script} | {p:.2f} | {sum(a.values()) / len(a):.3f} | {' '.join(cis)} |"
        )
