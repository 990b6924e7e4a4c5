"""How hard is a scene with several controlled cars, each running a scripted driver?

A first measurement for the multi-vehicle task (issue 41). The cars ``vehicle_0 ..
vehicle_{K-1}`` are all driven by the same scripted driver (default ``car_aware``, each on its
own ego-centric observation) on either
- every scene of a split of ``hbs-general`` (reactive traffic, ``params/table2g.json5``) that
  holds ``--cars`` cars, in ``--variations`` seeded variations of each; or
- ``--synthetic N``: N generated scenes with the cars through an intersection among
  ``--pedestrians`` crossing pedestrians (``CreateEnv.synthetic``, routes ``intersection``; seeds
  from ``--seed``).
Prints the per-car success, collision and timeout with Wilson intervals.

Usage: python benchmarks/multi_car_probe.py --pool out/table2g/pool-general.json [--cars 2]
       [--driver car_aware] [--split test] [--variations 1] [--json F]
       python benchmarks/multi_car_probe.py --synthetic 50 --cars 4 --pedestrians 20 [--seed 1000]
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np
import torch

from sharedspace.local_server import LocalServer
from sharedspace.pettingzoo_env import parallel_env
from sharedspace.scripted import SCRIPTED
from sharedspace.stats import wilson
from sharedspace.torchrl_env import synthetic_names
from sharedspace.wire.requests import SyntheticScenes

ROOT = Path(__file__).resolve().parents[1]


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument(
        "--pool", default=str(ROOT / "out" / "table2g" / "pool-general.json")
    )
    ap.add_argument("--params", default=str(ROOT / "params" / "table2g.json5"))
    ap.add_argument("--cars", type=int, default=2)
    ap.add_argument("--driver", default="car_aware", choices=sorted(SCRIPTED))
    ap.add_argument("--split", default="test")
    ap.add_argument("--variations", type=int, default=1)
    ap.add_argument("--max-agents", type=int, default=10)
    ap.add_argument(
        "--synthetic", type=int, default=0, help="generated intersection scenes"
    )
    ap.add_argument("--pedestrians", type=int, default=20, help="per generated scene")
    ap.add_argument(
        "--density", type=float, default=0.1, help="pedestrians per m², generated"
    )
    ap.add_argument(
        "--seed", type=int, default=1000, help="seed of the first generated scene"
    )
    ap.add_argument("--json")
    args = ap.parse_args()

    driver = SCRIPTED[args.driver]()
    agents = tuple(f"vehicle_{k}" for k in range(args.cars))
    outcomes: list[dict] = []
    cfg = [f"pools:[{json.dumps(args.pool)}]", f"params:{json.dumps(args.params)}"]
    if args.synthetic:
        source: dict = {
            "synthetic": {
                "layout": "crossing",
                "pedestrians": args.pedestrians,
                "density": args.density,
                "vehicles": args.cars,
                "routes": "intersection",
                "seed": args.seed,
                "scenes": args.synthetic,
            }
        }
    else:
        source = {"variations": {"position_sigma": 0.25, "start_offset_steps": 1}}
    with LocalServer(prefix="probe", cfg=cfg) as server:
        env = parallel_env(
            endpoint=server.endpoint,
            prefix="probe",
            split=args.split,
            external_agents=agents,
            max_agents=args.max_agents,
            **source,
        )
        if args.synthetic:
            scenes = [
                n
                for n, _ in synthetic_names(SyntheticScenes(**source["synthetic"]), "")
            ]
        else:
            _, names = env.client.scenarios()
            scenes = [name for name, split in names if split == args.split]
        for name in scenes:
            for v in range(args.variations):
                try:
                    options = {"scenario": name} | (
                        {} if args.synthetic else {"variation": v}
                    )
                    obs, _ = env.reset(seed=v, options=options)
                except Exception as e:  # fewer cars than asked: not a candidate
                    if "vehicle" in str(e):
                        break
                    raise
                ended: dict[str, str] = {}
                while env.agents:
                    feats = torch.as_tensor(
                        np.stack([obs[a]["features"] for a in env.agents])
                    )
                    mask = torch.as_tensor(
                        np.stack([obs[a]["mask"] for a in env.agents])
                    )
                    act = driver(feats, mask).numpy()
                    live = list(env.agents)
                    obs, _, terms, truncs, infos = env.step(
                        {a: act[i] for i, a in enumerate(live)}
                    )
                    for a in live:
                        if terms[a] or truncs[a]:
                            i = infos[a]
                            ended[a] = next(
                                (
                                    s
                                    for s in ("success", "collision", "timeout")
                                    if i[s]
                                ),
                                "timeout",
                            )
                for a, status in ended.items():
                    outcomes.append(
                        {"scene": name, "variation": v, "car": a, "status": status}
                    )
        env.close()
    n = len(outcomes)
    print(
        f"{args.driver} on {args.cars} cars per scene, {args.split} split: {n} car-episodes"
    )
    for status in ("success", "collision", "timeout"):
        k = sum(o["status"] == status for o in outcomes)
        lo, hi = wilson(k, n)
        print(f"  {status}: {k}/{n} = {k / max(n, 1):.3f} [{lo:.3f}, {hi:.3f}]")
    for a in agents:
        mine = [o for o in outcomes if o["car"] == a]
        k = sum(o["status"] == "success" for o in mine)
        print(f"  {a}: success {k}/{len(mine)}")
    if args.json:
        Path(args.json).write_text(
            json.dumps({"args": vars(args), "outcomes": outcomes})
        )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
