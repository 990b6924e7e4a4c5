"""Per-car outcomes on the crossing task's test scenes, and the figures built from them.

:func:`play` runs one episode of every test scene with every car driven by ``act`` (a function of
the grouped observation to the cars' actions), and returns one row per car and scene: how its
episode ended and whether a collision was with another car. The scripted baseline, a trained
policy and the planner's open-loop sequences all play through it, so their rows pair up by
(scene, car).
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from typing import Any

import numpy as np
import torch
from tensordict import TensorDictBase
from torchrl.envs.utils import ExplorationType, set_exploration_type

from sharedspace.client import Connection, SimClient
from sharedspace.episodes import STATUSES, outcome_rates
from sharedspace.marl.task import CrossingTask, make_env
from sharedspace.names import Feature
from sharedspace.outcomes import mean_by_episode
from sharedspace.scripted import SCRIPTED
from sharedspace.stats import paired_clustered
from sharedspace.train.envs import ResidualAction

__all__ = [
    "STATUSES",
    "Act",
    "paired_difference",
    "play",
    "policy_act",
    "scripted_act",
    "summarize",
]

#: ``act(td, step) -> actions [K, A, 2]`` (the env's actions, in [-1, 1]) from the grouped
#: observation ``td`` (keys ``("vehicle", "features")``, ``("vehicle", "mask")``) at step ``step``.
Act = Callable[[TensorDictBase, int], torch.Tensor]


def scripted_act(driver: str = "car_aware") -> Act:
    """Every car runs the scripted ``driver`` on its own observation."""
    module = SCRIPTED[driver]()

    def act(td: TensorDictBase, step: int) -> torch.Tensor:
        return module(td["vehicle", "features"], td["vehicle", "mask"])

    return act


def policy_act(policy: Any, base_driver: str = "", residual_scale: float = 1.0) -> Act:
    """A trained policy (a TensorDict module writing ``("vehicle", "action")``), deterministic;
    a residual learner's action goes to the env through the one residual transform
    (:class:`~sharedspace.train.envs.ResidualAction`), as in training."""
    residual = ResidualAction(base_driver, "vehicle", residual_scale) if base_driver else None

    def act(td: TensorDictBase, step: int) -> torch.Tensor:
        with torch.no_grad(), set_exploration_type(ExplorationType.DETERMINISTIC):
            out = policy(td.clone(False))
        if residual is not None:
            out = residual.inv(out)
        return out["vehicle", "action"]

    return act


def play(
    task: CrossingTask,
    act: Act,
    client: SimClient | Connection,
    *,
    split: str = "test",
    scenes: Sequence[str] | None = None,
    max_steps: int = 400,
) -> list[dict[str, Any]]:
    """One episode of each of ``scenes`` (default: every scene of ``split``) with the cars
    driven by ``act``: rows ``{scene, car, status, car_collision, steps, goal_dist}`` (the steps
    the car's episode took, its distance to the goal at the end): row ``i * cars + j`` is car
    ``j`` of sub-env ``i`` (``scenes[i]``; a scene may be listed more than once)."""
    names = list(scenes) if scenes is not None else task.scene_names(split)
    env = make_env(task, split, len(names), client, scenarios=names)
    k, a = len(names), task.cars
    status: list[list[str | None]] = [[None] * a for _ in range(k)]
    car_hit = np.zeros((k, a), dtype=bool)
    steps = np.zeros((k, a), dtype=np.int64)
    goal_dist = np.zeros((k, a))
    try:
        td = env.reset()
        for t in range(max_steps):
            td.set(("vehicle", "action"), act(td, t).to(torch.float32))
            out, td = env.step_and_maybe_reset(td)
            nxt = out["next", "vehicle"]
            flags = {s: nxt[f"episode_{s}"].reshape(k, a).numpy() for s in STATUSES}
            hit = nxt["episode_car_collision"].reshape(k, a).numpy()
            dist = nxt["features"][..., 0, Feature.GOAL_DIST].reshape(k, a).numpy()
            for i in range(k):
                for j in range(a):
                    if status[i][j] is not None:
                        continue
                    ended = next((s for s in STATUSES if flags[s][i, j]), None)
                    if ended is not None:
                        status[i][j], car_hit[i, j], steps[i, j] = ended, hit[i, j], t + 1
                        goal_dist[i, j] = dist[i, j]
            if all(s is not None for row in status for s in row):
                break
    finally:
        env.close()
    return [
        {
            "scene": names[i],
            "car": task.agents[j],
            "status": status[i][j] or "timeout",
            "car_collision": bool(car_hit[i, j]),
            "steps": int(steps[i, j]),
            "goal_dist": float(goal_dist[i, j]),
        }
        for i in range(k)
        for j in range(a)
    ]


def summarize(rows: Sequence[dict[str, Any]]) -> dict[str, Any]:
    """Per-car rates with Wilson 95 % intervals: ``success``, ``collision`` (any), ``timeout``,
    ``car_collision`` (with another car), over all cars, and each car's success."""
    out: dict[str, Any] = {"car_episodes": len(rows), **outcome_rates(rows, ("car_collision",))}
    cars = sorted({r["car"] for r in rows})
    out["success_by_car"] = {
        c: float(np.mean([r["status"] == "success" for r in rows if r["car"] == c])) for c in cars
    }
    return out


def paired_difference(
    rows: Sequence[dict[str, Any]],
    baseline: Sequence[dict[str, Any]],
    *,
    resamples: int = 10_000,
    seed: int = 0,
) -> dict[str, float]:
    """Success of ``rows`` minus ``baseline``'s on the same (scene, car) cells: the mean
    difference and a 95 % interval resampling scenes (the cars of one scene share its crowd;
    :func:`sharedspace.stats.paired_clustered`, the one paired difference). ``rows`` may hold
    several seeds' plays of the cells: a cell's outcome is their mean. A cell the baseline did
    not play is a ``KeyError``."""
    mine = mean_by_episode(
        rows, lambda r: (r["scene"], r["car"]), lambda r: r["status"] == "success"
    )
    base = {(r["scene"], r["car"]): float(r["status"] == "success") for r in baseline}
    missing = sorted(set(mine) - set(base))
    if missing:
        raise KeyError(f"cells the baseline did not play: {missing[:3]}")
    out = paired_clustered(mine, base, resamples, seed)
    return {"mean": out["diff"], "ci95": [out["lo"], out["hi"]]}
