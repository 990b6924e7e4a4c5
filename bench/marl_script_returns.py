"""What each outcome of a car-episode returns under a set of reward weights.

The car-aware script drives every car of the crossing task (``sharedspace.marl.task``) on 64
training scenes; each car's return is summed until its own episode ends and grouped by how it
ended. A learner's reward should order success > timeout > collision: under the world's
weights (danger 20, collision -20) a timeout spent beside a pedestrian returns less than a
collision, which is why ``sharedspace.marl.config.LEARNER_REWARD`` exists (docs/RESULTS.md).

Usage: python bench/marl_script_returns.py [--weights '{"danger": 2, "collision": -100}']
       [--envs 64] [--seed 5]
"""

from __future__ import annotations

import argparse
import json

import numpy as np
import torch

from sharedspace.client import Connection
from sharedspace.local_server import LocalServer
from sharedspace.marl.evaluate import STATUSES, scripted_act
from sharedspace.marl.task import CrossingTask, make_env


def script_returns(
    client, weights: dict | None, envs: int, seed: int
) -> dict[str, list[float]]:
    """Each car's return of its first episode in each of ``envs`` training scenes, by status."""
    task = CrossingTask()
    env = make_env(task, "train", envs, client, seed=seed, reward_weights=weights)
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


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument(
        "--weights", default="", help="reward weights as JSON; '' = the world's"
    )
    ap.add_argument(
        "--envs", type=int, default=64, help="training scenes, one episode each"
    )
    ap.add_argument(
        "--seed", type=int, default=5, help="seed of the draw of training scenes"
    )
    args = ap.parse_args()
    weights = json.loads(args.weights) if args.weights else None
    with LocalServer(prefix="returns") as server:
        client = Connection(endpoint=server.endpoint, prefix="returns").open()
        try:
            by_status = script_returns(client, weights, args.envs, args.seed)
        finally:
            client.shutdown()
    print(f"reward weights: {weights or 'the world defaults'}")
    for status, values in by_status.items():
        if values:
            p10, p90 = np.percentile(values, [10, 90])
            print(
                f"{status:9s} {len(values):4d} car-episodes, mean return {np.mean(values):7.1f} "
                f"(p10 {p10:.1f}, p90 {p90:.1f})"
            )


if __name__ == "__main__":
    main()
