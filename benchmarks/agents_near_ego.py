"""How many agents are near the ego on the hbs-general test split (the human record replayed):
the measurement behind Table II-G's max_agents. Run from the repository root:

    .venv/bin/python benchmarks/agents_near_ego.py
"""

import json
import subprocess
import numpy as np

counts = {5: [], 10: [], 15: []}
k = 0
while True:
    p = subprocess.run(
        [
            "target/release/sim-server",
            "rollout",
            "--pool",
            "embedded:hbs-general",
            "--scenario",
            str(k),
            "--params",
            "params/table2g.json5",
        ],
        capture_output=True,
        text=True,
    )
    if p.returncode:
        break
    lines = [json.loads(line) for line in p.stdout.splitlines()]
    h = lines[0]
    k += 1
    if h["split"] != "test":
        continue
    ego = h["ego"]
    for step in lines[1:]:
        if step.get("type") != "step":
            continue
        ag = {a["id"]: (a["x"], a["y"]) for a in step["agents"]}
        if ego not in ag:
            continue
        ex, ey = ag[ego]
        d = np.array([np.hypot(x - ex, y - ey) for i, (x, y) in ag.items() if i != ego])
        for r in counts:
            counts[r].append(int((d <= r).sum()))
for r, c in counts.items():
    c = np.array(c)
    print(
        r,
        "m: steps",
        len(c),
        "mean %.1f" % c.mean(),
        "p50/p90/p95/p99/max",
        np.percentile(c, [50, 90, 95, 99]).tolist(),
        c.max(),
    )
