"""Scripted reference drivers and the kinematic reachability of each scenario's goal.

They say what a learned policy must beat (docs/RESULTS.md, Table II) and whether the paper's
success rate is reachable on our scenario extraction at all:

- :class:`HoldDriver` holds the initial speed and heading (action ``[0, 0]``): doing nothing.
- :class:`StopDriver` brakes to a standstill: what collides even then is unavoidable.
- :class:`HumanReplayDriver` replays the recorded driver's speed and heading changes open loop
  among the simulated pedestrians.
- :class:`PursuitDriver` steers toward the goal within the yaw-rate limit at a cruise speed,
  slows where the turn to the goal needs a tighter circle than the yaw-rate limit allows at its
  speed, and brakes to a stop while a pedestrian is close ahead.
- :class:`CarAwareDriver` steers like the pursuit but sets its speed by the intelligent driver
  model (IDM) behind the nearest agent in its path, pedestrian or car, and also behind one whose
  motion brings it into the path by the time the car gets there.
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
from dataclasses import dataclass
from typing import Any

import numpy as np
import torch
from tensordict.nn import TensorDictModule
from torch import nn

from sharedspace.names import Feature

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

# Node feature columns (protocol/SPEC.md section 7).
_REL_X, _REL_Y, _SPEED = Feature.REL_X, Feature.REL_Y, Feature.SPEED
_GOAL_DX, _GOAL_DY, _GOAL_DIST = Feature.GOAL_DX, Feature.GOAL_DY, Feature.GOAL_DIST
_REL_VX, _REL_VY, _RADIUS = Feature.REL_VX, Feature.REL_VY, Feature.RADIUS
_HEADING_DIFF = Feature.HEADING_DIFF


@dataclass(frozen=True)
class VehicleLimits:
    """model.md section 2 (sim-core ``VehicleParams``)."""

    acc_max: float = 2.0  # m/s^2: action[0] = acc / acc_max
    omega_max: float = 0.2  # rad/s: action[1] = omega / omega_max
    speed_max: float = 6.0  # m/s
    goal_radius: float = 2.0  # m
    dt: float = 0.5  # s


def _turn_speed_cap(limits: VehicleLimits, heading_error, goal_dist):
    """Highest speed at which the circle of the yaw-rate limit still passes through the goal
    (radius ``v / omega_max`` at most ``d / (2 sin|e|)``), for arrays or floats."""
    sin_e = np.abs(np.sin(heading_error))
    with np.errstate(divide="ignore"):
        return np.where(sin_e > 1e-6, limits.omega_max * goal_dist / (2 * sin_e), np.inf)


def pursuit_action(
    heading_error,
    goal_dist,
    speed,
    cruise: float,
    limits: VehicleLimits,
    brake=None,
) -> tuple[Any, Any]:
    """(acc, omega), physical units, of the pursuit law; arrays broadcast. ``brake`` (bool)
    sets the target speed to 0."""
    omega = np.clip(heading_error / limits.dt, -limits.omega_max, limits.omega_max)
    target = np.minimum(cruise, _turn_speed_cap(limits, heading_error, goal_dist))
    target = np.maximum(target, 0.5)  # never stall for the turn cap alone
    if brake is not None:
        target = np.where(brake, 0.0, target)
    acc = np.clip((target - speed) / limits.dt, -limits.acc_max, limits.acc_max)
    return acc, omega


class HoldDriver(nn.Module):
    """Action ``[0, 0]``: the initial speed and heading, whatever happens."""

    def forward(self, features: torch.Tensor, mask: torch.Tensor) -> torch.Tensor:
        return features.new_zeros((*features.shape[:-2], 2))


class StopDriver(nn.Module):
    """Full braking, straight on: the least an AV can do to avoid anyone."""

    def forward(self, features: torch.Tensor, mask: torch.Tensor) -> torch.Tensor:
        action = features.new_zeros((*features.shape[:-2], 2))
        action[..., 0] = -1.0
        return action


class PursuitDriver(nn.Module):
    """Pure pursuit toward the goal at ``cruise`` m/s, braking to a stop while a present
    pedestrian's centre is within ``brake_ahead`` m ahead and ``brake_side`` m to either side.

    Args:
        cruise: target speed, m/s.
        brake_ahead, brake_side: the braking box in the ego frame, m.
        limits: vehicle limits (the action normalisation).
    """

    def __init__(
        self,
        cruise: float = 3.0,
        brake_ahead: float = 8.0,
        brake_side: float = 2.5,
        limits: VehicleLimits = VehicleLimits(),  # noqa: B008 - frozen dataclass
    ):
        super().__init__()
        self.cruise, self.brake_ahead, self.brake_side = cruise, brake_ahead, brake_side
        self.limits = limits

    def forward(self, features: torch.Tensor, mask: torch.Tensor) -> torch.Tensor:
        f = features.detach().cpu().numpy()
        present = mask.detach().cpu().numpy().astype(bool)
        ego = f[..., 0, :]
        heading_error = np.arctan2(ego[..., _GOAL_DY], ego[..., _GOAL_DX])
        others = f[..., 1:, :]
        is_ped = others[..., Feature.IS_VEHICLE] < 0.5
        ahead = (others[..., _REL_X] > 0.0) & (others[..., _REL_X] < self.brake_ahead)
        beside = np.abs(others[..., _REL_Y]) < self.brake_side
        brake = (present[..., 1:] & is_ped & ahead & beside).any(-1)
        acc, omega = pursuit_action(
            heading_error, ego[..., _GOAL_DIST], ego[..., _SPEED], self.cruise, self.limits, brake
        )
        action = np.stack([acc / self.limits.acc_max, omega / self.limits.omega_max], -1)
        return torch.as_tensor(action, dtype=features.dtype, device=features.device)


class CarAwareDriver(nn.Module):
    """Pursuit toward the goal whose speed follows the intelligent driver model (Treiber et al.,
    2000) behind the first agent in its path: pedestrians and cars alike.

    An agent is in the path when its centre is ahead of the car's front and, now or when the car
    would reach it (its lateral velocity carried over ``rel_x / speed`` seconds, at most
    ``lookahead`` s), within ``half_width + radius + margin`` of the car's axis. The gap is its
    distance ahead less the car's half length and its radius; its speed along the car's axis
    is the car's speed plus ``rel_vx``. The IDM acceleration
    ``a (1 - (v / cruise)^4 - (s* / s)^2)``, ``s* = s0 + v T + v dv / (2 sqrt(a b))``, caps the
    pursuit's; with no one in the path the pursuit drives alone.

    The defaults are the best of a grid on Table II-G's train split (``python -m
    sharedspace.paper.tune``, results/table2g/car_aware_tuning.json: success 0.900, collision
    0.070 over 458 train episodes); the test split was never played to choose them.

    Args:
        cruise: desired speed ``v0``, m/s.
        headway: time headway ``T``, s.
        min_gap: standstill gap ``s0``, m.
        margin: lateral clearance added to the path's half width, m.
        lookahead: the longest time ahead a crossing agent is projected, s.
        comfort_decel: IDM's comfortable deceleration ``b``, m/s^2.
        half_length, half_width: the car's footprint (model.md section 2: 4.0 x 1.8 m), m.
        limits: vehicle limits (``acc_max`` is IDM's ``a``; the action normalisation).
    """

    def __init__(
        self,
        cruise: float = 3.5,
        headway: float = 1.5,
        min_gap: float = 2.5,
        margin: float = 0.0,
        lookahead: float = 2.0,
        comfort_decel: float = 2.0,
        half_length: float = 2.0,
        half_width: float = 0.9,
        limits: VehicleLimits = VehicleLimits(),  # noqa: B008 - frozen dataclass
    ):
        super().__init__()
        self.cruise, self.headway, self.min_gap = cruise, headway, min_gap
        self.margin, self.lookahead, self.comfort_decel = margin, lookahead, comfort_decel
        self.half_length, self.half_width = half_length, half_width
        self.limits = limits

    def idm_acceleration(self, f: np.ndarray, present: np.ndarray) -> np.ndarray:
        """IDM's acceleration ``[*]`` behind the first agent in the path (``+inf`` when the path
        is free) of node features ``f [*, M, F]`` and mask ``present [*, M]``."""
        v = f[..., 0, _SPEED][..., None]
        others = f[..., 1:, :]
        x, y = others[..., _REL_X], others[..., _REL_Y]
        reach = np.clip(x / np.maximum(v, 1.0), 0.0, self.lookahead)
        y_then = y + others[..., _REL_VY] * reach
        # Half the other's extent across the car's axis: its radius for a pedestrian; for a car
        # (taken to have this car's footprint; the observation gives only its radius) the
        # rectangle's, so a parked car alongside is not in the path.
        hd = others[..., _HEADING_DIFF]
        across = self.half_length * np.abs(np.sin(hd)) + self.half_width * np.abs(np.cos(hd))
        extent = np.where(others[..., Feature.IS_VEHICLE] > 0.5, across, others[..., _RADIUS])
        corridor = self.half_width + extent + self.margin
        in_path = (
            present[..., 1:]
            & (x > 0.0)
            & ((np.abs(y) < corridor) | (np.abs(y_then) < corridor) | (y * y_then < 0.0))
        )
        along = self.half_length * np.abs(np.cos(hd)) + self.half_width * np.abs(np.sin(hd))
        ahead = np.where(others[..., Feature.IS_VEHICLE] > 0.5, along, others[..., _RADIUS])
        gap = np.maximum(x - self.half_length - ahead, 1e-3)
        closing = v - (v + others[..., _REL_VX])  # v - v_leader along the car's axis
        a, b = self.limits.acc_max, self.comfort_decel
        desired = self.min_gap + np.maximum(
            0.0, v * self.headway + v * closing / (2.0 * np.sqrt(a * b))
        )
        acc = a * (1.0 - (v / self.cruise) ** 4 - (desired / gap) ** 2)
        return np.where(in_path, acc, np.inf).min(-1)

    def forward(self, features: torch.Tensor, mask: torch.Tensor) -> torch.Tensor:
        f = features.detach().cpu().numpy().astype(np.float64)
        present = mask.detach().cpu().numpy().astype(bool)
        ego = f[..., 0, :]
        heading_error = np.arctan2(ego[..., _GOAL_DY], ego[..., _GOAL_DX])
        acc, omega = pursuit_action(
            heading_error, ego[..., _GOAL_DIST], ego[..., _SPEED], self.cruise, self.limits
        )
        acc = np.minimum(acc, self.idm_acceleration(f, present))
        acc = np.clip(acc, -self.limits.acc_max, self.limits.acc_max)
        action = np.stack([acc / self.limits.acc_max, omega / self.limits.omega_max], -1)
        return torch.as_tensor(action, dtype=features.dtype, device=features.device)


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


#: Reference drivers by name (``evaluate --driver NAME``; Table II rows).
DRIVERS = {
    "hold": lambda: HoldDriver(),
    "stop": lambda: StopDriver(),
    "pursuit_3": lambda: PursuitDriver(cruise=3.0),
    "pursuit_5": lambda: PursuitDriver(cruise=5.0),
    "car_aware": lambda: CarAwareDriver(),
}


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
