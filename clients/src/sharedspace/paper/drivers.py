"""Scripted reference drivers and the kinematic reachability of each scenario's goal.

They say what a learned policy must beat (docs/RESULTS.md, Table II) and whether the paper's
success rate is reachable on our scenario extraction at all:

- the scripted drivers of :mod:`sharedspace.scripted` (``hold``: doing nothing; ``stop``: what
  collides even then is unavoidable; ``pursuit_3`` / ``pursuit_5``: pursuit braking for
  pedestrians ahead; ``car_aware``: the IDM pursuit that follows anyone in its path);
- :class:`HumanReplayDriver` replays the recorded driver's speed and heading changes open loop
  among the simulated pedestrians.
- :func:`reachability` plays, for every scenario, the pursuit law with no pedestrians from the
  recorded initial state at every cruise speed of a grid and reports the earliest arrival within
  the horizon, with the vehicle limits of model.md section 2.

The drivers read only the observation (ENV_CONTRACT.md: ego-frame node features, mask), so
they run through the same evaluator and env as a learned actor
(``python -m sharedspace.paper.evaluate --driver pursuit``).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Any

import numpy as np
import torch
from tensordict.nn import TensorDictModule
from torch import nn

from sharedspace.scripted import (
    SCRIPTED,
    CarAwareDriver,
    HoldDriver,
    PursuitDriver,
    StopDriver,
    VehicleLimits,
    pursuit_action,
)

__all__ = [
    "DRIVERS",
    "VehicleLimits",
    "HoldDriver",
    "HumanReplayDriver",
    "StopDriver",
    "PursuitDriver",
    "CarAwareDriver",
    "make_driver",
    "reachability",
]


class HumanReplayDriver(nn.Module):
    """The recorded driver's speeds and headings replayed open loop as actions: at step ``t``
    the acceleration and yaw rate that take the recorded speed and heading of frame ``t`` to
    those of frame ``t + 1`` (clipped to the limits), then full braking after the record ends.
    It reads ``scenario_index`` and counts its calls, so it plays one episode per sub-env, all
    started together (as the evaluator plays them).

    Args:
        pool: the scenario dicts of the pool (``scenario_index`` indexes it).
    """

    def __init__(self, pool: Sequence[dict[str, Any]], limits: VehicleLimits = VehicleLimits()):  # noqa: B008
        super().__init__()
        from sharedspace.pool import recorded_headings

        self.limits = limits
        self.speeds, self.headings = [], []
        for sc in pool:
            vel = np.asarray(sc["agents"][int(sc["ego"])]["velocities"], dtype=float)
            vel = vel.reshape(-1, 2)
            self.speeds.append(np.hypot(vel[:, 0], vel[:, 1]))
            self.headings.append(np.asarray(recorded_headings(vel), dtype=float))
        self.t = 0

    def forward(self, scenario_index: torch.Tensor, features: torch.Tensor) -> torch.Tensor:
        lim = self.limits
        out = np.zeros((len(scenario_index.reshape(-1)), 2))
        for k, idx in enumerate(scenario_index.reshape(-1).tolist()):
            v, th = self.speeds[int(idx)], self.headings[int(idx)]
            if self.t + 1 < len(v):
                acc = (v[self.t + 1] - v[self.t]) / lim.dt
                turn = th[self.t + 1] - th[self.t]
                omega = math.atan2(math.sin(turn), math.cos(turn)) / lim.dt
                out[k] = (acc / lim.acc_max, omega / lim.omega_max)
            else:
                out[k] = (-1.0, 0.0)
        self.t += 1
        return torch.as_tensor(np.clip(out, -1.0, 1.0), dtype=features.dtype).reshape(
            *features.shape[:-2], 2
        )


#: Reference drivers by name (``evaluate --driver NAME``; Table II rows): the scripted ones of
#: :mod:`sharedspace.scripted`.
DRIVERS = SCRIPTED


def make_driver(name: str, pool: Sequence[dict[str, Any]] | None = None) -> TensorDictModule:
    """A driver of :data:`DRIVERS` (or ``human_replay``, which needs the scenario ``pool``) as
    a policy over the env's tensordicts. A driver keeps no state but ``human_replay``'s step
    count: make a new one per evaluation."""
    if name == "human_replay":
        if pool is None:
            from sharedspace.pool import load_pool

            pool = load_pool()
        return TensorDictModule(
            HumanReplayDriver(pool), in_keys=["scenario_index", "features"], out_keys=["action"]
        )
    if name not in DRIVERS:
        raise ValueError(f"unknown driver {name!r}; known: {', '.join([*DRIVERS, 'human_replay'])}")
    return TensorDictModule(DRIVERS[name](), in_keys=["features", "mask"], out_keys=["action"])


def reachability(
    scenarios: Sequence[dict[str, Any]],
    horizon_extra: float = 15.0,
    cruises: Sequence[float] = (1.0, 1.5, 2.0, 2.5, 3.0, 3.5, 4.0, 4.5, 5.0, 5.5, 6.0),
    limits: VehicleLimits = VehicleLimits(),  # noqa: B008 - frozen dataclass
) -> list[dict[str, Any]]:
    """Per scenario, the pursuit law with no pedestrians from the recorded initial state
    (position, speed, heading of the first frame), the semi-implicit unicycle of model.md
    section 2, for each cruise speed: the earliest arrival step within the horizon (recorded
    steps + ``horizon_extra`` s), or ``None`` if no cruise speed arrives."""
    from sharedspace.pool import recorded_headings

    out = []
    for sc in scenarios:
        ego = sc["agents"][int(sc["ego"])]
        pos = np.asarray(ego["positions"], dtype=float).reshape(-1, 2)
        vel = np.asarray(ego["velocities"], dtype=float).reshape(-1, 2)
        dt = float(sc.get("dt", limits.dt))
        recorded_steps = len(pos) - 1
        horizon = recorded_steps + int(round(horizon_extra / dt))
        goal = pos[-1]
        theta0 = float(recorded_headings(vel)[0])
        best: dict[str, Any] = {"steps": None, "cruise": None}
        for cruise in cruises:
            x, y, th, v = float(pos[0, 0]), float(pos[0, 1]), theta0, float(np.hypot(*vel[0]))
            for step in range(1, horizon + 1):
                dx, dy = goal[0] - x, goal[1] - y
                err = math.atan2(dy, dx) - th
                err = math.atan2(math.sin(err), math.cos(err))
                acc, omega = pursuit_action(err, math.hypot(dx, dy), v, cruise, limits)
                v = min(max(v + float(acc) * dt, 0.0), limits.speed_max)
                th += float(omega) * dt
                x += v * math.cos(th) * dt
                y += v * math.sin(th) * dt
                if math.hypot(goal[0] - x, goal[1] - y) <= limits.goal_radius:
                    if best["steps"] is None or step < best["steps"]:
                        best = {"steps": step, "cruise": cruise}
                    break
        out.append(
            {
                "scenario": sc["name"],
                "horizon_steps": horizon,
                "recorded_steps": recorded_steps,
                "initial_speed": float(np.hypot(*vel[0])),
                "reachable": best["steps"] is not None,
                "earliest_arrival_steps": best["steps"],
                "at_cruise": best["cruise"],
            }
        )
    return out
