"""Matched-budget comparison: G-SAC-Cog trained on the paper pool vs on paper+general scenes,
both at the same frame count, on the 18 paper test scenes (3 seeds each).

    .venv/bin/python benchmarks/matched_budget.py ENDPOINT step_160000.pt \
        AUG_RUNS PAPER_RUNS OUT.json

against a server with params/table2.json5 serving embedded:hbs-paper and the paper+general pool
file (docs/RESULTS.md, "Reading Table II"). AUG_RUNS' last.pt must be at the same frame count
as PAPER_RUNS' named checkpoint."""

import json
import sys
from pathlib import Path

import numpy as np

from sharedspace.paper.evaluate import evaluate_policy
from sharedspace.train.learners import load_checkpoint_actor
from sharedspace.train.checkpoint import read_checkpoint
from sharedspace.stats import wilson, sign_test, paired_bootstrap

ep, frames_name, aug_dir, base_dir, out = sys.argv[1:6]
ov = [f"server_endpoint={ep}"]
res = {}
for label, pattern in (
    ("paper pool", f"{base_dir}/g_sac_cog-s{{s}}/checkpoints/{frames_name}"),
    ("paper + general", f"{aug_dir}/g_sac_cog-s{{s}}/checkpoints/last.pt"),
):
    runs = []
    for s in range(3):
        ck = pattern.format(s=s)
        cfg, actor = load_checkpoint_actor(ck, ov)
        fr = int(read_checkpoint(ck)["counters"]["frames"])
        r = evaluate_policy(cfg.world, actor, "test", seed=cfg.seed, driving=cfg.driving)
        runs.append(
            {
                "checkpoint": ck,
                "frames": fr,
                "summary": r["summary"],
                "status": {
                    int(e["scenario_index"]): e["status"] for e in r["episodes"]
                },
            }
        )
        print(
            label, s, fr, r["summary"]["success"], r["summary"]["collision"], flush=True
        )
    res[label] = runs
idx = sorted(res["paper pool"][0]["status"])


def per_scene(label):
    return np.array(
        [np.mean([r["status"][i] == "success" for r in res[label]]) for i in idx]
    )


a, b = per_scene("paper + general"), per_scene("paper pool")
diff = a - b
summary = {}
for label, runs in res.items():
    k = sum(st == "success" for r in runs for st in r["status"].values())
    n = sum(len(r["status"]) for r in runs)
    c = sum(st == "collision" for r in runs for st in r["status"].values())
    summary[label] = {
        "success": k,
        "collision": c,
        "n": n,
        "wilson_success": wilson(k, n),
        "per_seed_success": [r["summary"]["success"] for r in runs],
        "per_seed_speed": [r["summary"].get("avg_speed") for r in runs],
    }
better, worse = int((diff > 0).sum()), int((diff < 0).sum())
summary["paired"] = {
    "mean_diff": float(diff.mean()),
    "bootstrap95": paired_bootstrap(list(diff)),
    "better": better,
    "worse": worse,
    "ties": int((diff == 0).sum()),
    "sign_test_p": sign_test(better, worse),
}
Path(out).write_text(
    json.dumps({"summary": summary, "runs": res}, indent=1, default=str)
)
print(json.dumps(summary, indent=1, default=str))
