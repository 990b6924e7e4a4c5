"""The planner's bound on Table II-G: can any driver succeed on the 76 hbs-general test scenes?

The open-loop cross-entropy search of Table II (`sharedspace.train.planner.open_loop_search`)
on the Table II-G world (params/table2g.json5, reactive cars, max_agents 10): per test scene,
round 0 plays the 9 constant actions and random piecewise-constant sequences, later rounds
sample around the best so far; every successful sequence is replayed in a fresh env. A
replayed success proves that a collision-free arrival exists there. Run from the repository
root (after `make table2g` extracted out/table2g/pool-general.json, or with --pool):

    .venv/bin/python results/table2g/planner_bound.py [--rounds 8] [--per-round 48]

Writes results/table2g/planner_bound.json.
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

from sharedspace.local_server import LocalServer
from sharedspace.train.config import TrainConfig
from sharedspace.train.planner import open_loop_search

HERE = Path(__file__).resolve().parent


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--rounds", type=int, default=8, help="search rounds per scene")
    ap.add_argument("--per-round", type=int, default=48, help="sequences per scene and round")
    ap.add_argument("--pool", default="out/table2g/pool-general.json", help="general pool file")
    ap.add_argument("--out", default=str(HERE / "planner_bound.json"))
    args = ap.parse_args()
    t0 = time.time()
    with LocalServer(
        cfg=[f'pools:["{args.pool}"]', 'params:"params/table2g.json5"']
    ) as server:
        cfg = TrainConfig(
            env_backend="remote",
            server_endpoint=server.endpoint,
            scenario_pool=args.pool,
            max_agents=10,
        )
        found = open_loop_search(cfg, rounds=args.rounds, per_round=args.per_round)
    solved = sorted(n for n, r in found.items() if r.get("replayed") == "success")
    summary = {
        "date": time.strftime("%Y-%m-%d %H:%M UTC", time.gmtime()),
        "rounds": args.rounds,
        "per_round": args.per_round,
        "scenes": len(found),
        "solved": len(solved),
        "success_reachable": len(solved) / max(1, len(found)),
        "unsolved": sorted(set(found) - set(solved)),
        "minutes": round((time.time() - t0) / 60, 1),
        "per_scene": {
            n: {k: v for k, v in r.items() if k != "best_actions"} for n, r in found.items()
        },
    }
    Path(args.out).write_text(json.dumps(summary, indent=1))
    print(
        f"planner bound: a replayed collision-free arrival in {len(solved)} of {len(found)} "
        f"test scenes ({summary['success_reachable']:.3f}); {summary['minutes']} min"
    )


if __name__ == "__main__":
    main()
