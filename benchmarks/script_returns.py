"""What each outcome of the car-aware script's episodes returns under each named reward, in
both worlds a learner trains in (the table behind ``sharedspace.train.reward``).

- ``crowd``: Table II-G's world (hbs-general with reacting cars, params/table2g.json5,
  ``max_agents`` 10, the training variations): every train scene once, one car;
- ``crossing``: the crossing task (``sharedspace.marl.task``, 4 cars): ``--envs`` training scenes,
  each car's return summed until its own episode ends.

A learner's reward should order success > timeout > collision. Under the world's weights a
timeout spent beside a pedestrian returns less than a collision; under ``learner`` it does not.

Usage: python benchmarks/script_returns.py [--pool out/table2g/pool-general.json] [--envs 64]
       [--seed 5] [--json out.json]
"""

from __future__ import annotations

import argparse
import json

import numpy as np
import torch

from sharedspace.marl.evaluate import STATUSES, scripted_act
from sharedspace.marl.task import CrossingTask
from sharedspace.marl.task import make_env as make_crossing_env
from sharedspace.pool import load_pool, split_indices
from sharedspace.scripted import SCRIPTED
from sharedspace.train.config import TrainConfig
from sharedspace.train.envs import make_env
from sharedspace.train.reward import REWARDS

#: Table II-G's world as the learners train in it (the Makefile's TABLE2G_WORLD).
CROWD_WORLD = {
    "max_agents": 10,
    "server_params": "params/table2g.json5",
    "variations": {
        "position_sigma": 0.5,
        "start_offset_steps": 2,
        "desired_speed_scale": 0.2,
        "mirror": True,
    },
}


def crowd_returns(pool: str, reward: str, seed: int) -> dict[str, list[float]]:
    """The script's return of one episode in every train scene of the crowd world."""
    cfg = TrainConfig(scenario_pool=pool, reward=reward, seed=seed, **CROWD_WORLD)
    n = len(split_indices(load_pool(pool), "train"))
    env = make_env(
        cfg.world,
        "train",
        n,
        cfg.seed,
        "sequential",
        variations=cfg.world.variations,
        driving=cfg.driving,
    )
    driver = SCRIPTED["car_aware"]()
    td = env.reset()
    total = torch.zeros(n)
    ended = torch.zeros(n, dtype=torch.bool)
    by_status: dict[str, list[float]] = {s: [] for s in STATUSES}
    while not ended.all():
        td.set("action", driver(td["features"], td["mask"]))
        out, td = env.step_and_maybe_reset(td)
        nxt = out["next"]
        total += nxt["reward"][:, 0] * ~ended
        for status in STATUSES:
            for k in (nxt[f"episode_{status}"][:, 0] & ~ended).nonzero()[:, 0].tolist():
                by_status[status].append(float(total[k]))
        ended |= nxt["done"][:, 0]
    env.close()
    return by_status


def crossing_returns(
    client, reward: str, envs: int, seed: int
) -> dict[str, list[float]]:
    """Each car's return of its first episode in each of ``envs`` crossing training scenes."""
    task = CrossingTask()
    env = make_crossing_env(
        task, "train", envs, client, seed=seed, reward_weights=REWARDS[reward]
    )
    act = scripted_act("car_aware")
    td = env.reset()
    total = torch.zeros(envs, task.cars)
    ended = torch.zeros(envs, task.cars, dtype=torch.bool)
    by_status: dict[str, list[float]] = {s: [] for s in STATUSES}
    step = 0
    while not ended.all():
        td.set(("vehicle", "action"), act(td, step))
        out, td = env.step_and_maybe_reset(td)
        nxt = out["next", "vehicle"]
        total += nxt["reward"][..., 0] * ~ended
        for status in STATUSES:
            for k, a in (nxt[f"episode_{status}"][..., 0] & ~ended).nonzero().tolist():
                by_status[status].append(float(total[k, a]))
        ended |= nxt["done"][..., 0]
        step += 1
    env.close()
    return by_status


def row(world: str, reward: str, by_status: dict[str, list[float]]) -> dict:
    """Count and mean return per outcome, and whether they order success > timeout >
    collision (an outcome that never happened does not break the order)."""
    out: dict = {"world": world, "reward": reward}
    for status, values in by_status.items():
        out[status] = {
            "n": len(values),
            "mean": float(np.mean(values)) if values else None,
        }
    means = [out[s]["mean"] for s in ("success", "timeout", "collision")]
    present = [m for m in means if m is not None]
    out["ordered"] = all(a > b for a, b in zip(present, present[1:], strict=False))
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument(
        "--pool", default="out/table2g/pool-general.json", help="crowd world's pool"
    )
    ap.add_argument("--envs", type=int, default=64, help="crossing training scenes")
    ap.add_argument(
        "--seed", type=int, default=5, help="seed of the draws of training scenes"
    )
    ap.add_argument("--json", default="", help="also write the rows here")
    args = ap.parse_args()
    rows = []
    for reward in REWARDS:
        rows.append(row("crowd", reward, crowd_returns(args.pool, reward, args.seed)))
    crossing = (
        TrainConfig().connection().open()
    )  # a local server (the task sends its crowd)
    try:
        for reward in REWARDS:
            rows.append(
                row(
                    "crossing",
                    reward,
                    crossing_returns(crossing, reward, args.envs, args.seed),
                )
            )
    finally:
        crossing.shutdown()
    print(
        "| world | reward | success: n, mean return | timeout | collision | ordered |"
    )
    print("|---|---|---|---|---|---|")
    for r in rows:
        cells = [
            f"{r[s]['n']}, {r[s]['mean']:+.1f}"
            if r[s]["mean"] is not None
            else f"{r[s]['n']}, -"
            for s in ("success", "timeout", "collision")
        ]
        print(
            f"| {r['world']} | {r['reward']} {REWARDS[r['reward']] or ''} | "
            + " | ".join(cells)
            + f" | {r['ordered']} |"
        )
    if args.json:
        with open(args.json, "w") as f:
            json.dump(rows, f, indent=1)


if __name__ == "__main__":
    main()
