"""Scripted drivers: closed-form policies over the observation (ENV_CONTRACT.md: ego-frame node
features and mask), with no state.

- :class:`HoldDriver` holds the initial speed and heading (action ``[0, 0]``);
- :class:`StopDriver` brakes to a standstill;
- :class:`PursuitDriver` steers toward the goal within the yaw-rate limit at a cruise speed,
  slows where the turn to the goal needs a tighter circle than the yaw-rate limit allows at its
  speed, and brakes to a stop while a pedestrian is close ahead;
- :class:`CarAwareDriver` steers like the pursuit but sets its speed by the intelligent driver
  model (IDM) behind the nearest agent in its path, pedestrian or car, and also behind one whose
  motion brings it into the path by the time the car gets there.

They are the reference rows of the tables (:mod:`sharedspace.paper.drivers` names them) and the
base a residual policy adds its action to (the trainer's ``base_driver``).

Each is NumPy alone: the benchmark scores them with no torch loaded. Called on torch tensors (a
TorchRL transform, a prior's actions), a driver computes the same actions and hands them back as
a tensor of the features' dtype and device.
"""

from __future__ import annotations

import sys
from abc import ABC, abstractmethod
from dataclasses import dataclass
from typing import Any

import numpy as np

from sharedspace.names import Feature

__all__ = [
    "SCRIPTED",
    "VehicleLimits",
    "pursuit_action",
    "ScriptedDriver",
    "HoldDriver",
    "StopDriver",
    "PursuitDriver",
    "CarAwareDriver",
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
    with np.errstate(divide="ignore", invalid="ignore"):  # 0/0 where the where() drops it
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


class ScriptedDriver(ABC):
    """A closed-form driver: :meth:`act` maps node features ``[*, M, F]`` and the mask
    ``[*, M]`` (bool) to normalised actions ``[*, 2]`` (acceleration, yaw rate). Calling it
    takes NumPy arrays or torch tensors and gives back the same kind, in the features' dtype."""

    @abstractmethod
    def act(self, features: np.ndarray, mask: np.ndarray) -> np.ndarray:
        """The actions of a batch of observations, NumPy in and out."""

    def __call__(self, features: Any, mask: Any) -> Any:
        if isinstance(features, np.ndarray):
            action = self.act(features, np.asarray(mask).astype(bool))
            return action.astype(features.dtype, copy=False)
        # A tensor: torch is loaded already, by whoever made it.
        torch = sys.modules["torch"]
        f = features.detach().cpu().numpy()
        action = self.act(f, mask.detach().cpu().numpy().astype(bool))
        return torch.as_tensor(action, dtype=features.dtype, device=features.device)


class HoldDriver(ScriptedDriver):
    """Action ``[0, 0]``: the initial speed and heading, whatever happens."""

    def act(self, features: np.ndarray, mask: np.ndarray) -> np.ndarray:
        return np.zeros((*features.shape[:-2], 2), dtype=features.dtype)


class StopDriver(ScriptedDriver):
    """Full braking, straight on: the least an AV can do to avoid anyone."""

    def act(self, features: np.ndarray, mask: np.ndarray) -> np.ndarray:
        action = np.zeros((*features.shape[:-2], 2), dtype=features.dtype)
        action[..., 0] = -1.0
        return action


class PursuitDriver(ScriptedDriver):
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
        self.cruise, self.brake_ahead, self.brake_side = cruise, brake_ahead, brake_side
        self.limits = limits

    def act(self, features: np.ndarray, mask: np.ndarray) -> np.ndarray:
        f, present = features, mask
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
        return np.stack([acc / self.limits.acc_max, omega / self.limits.omega_max], -1)


class CarAwareDriver(ScriptedDriver):
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
        closing = -others[..., _REL_VX]  # v - v_leader along the car's axis
        a, b = self.limits.acc_max, self.comfort_decel
        desired = self.min_gap + np.maximum(
            0.0, v * self.headway + v * closing / (2.0 * np.sqrt(a * b))
        )
        acc = a * (1.0 - (v / self.cruise) ** 4 - (desired / gap) ** 2)
        return np.where(in_path, acc, np.inf).min(-1)

    def act(self, features: np.ndarray, mask: np.ndarray) -> np.ndarray:
        f, present = features.astype(np.float64), mask
        ego = f[..., 0, :]
        heading_error = np.arctan2(ego[..., _GOAL_DY], ego[..., _GOAL_DX])
        acc, omega = pursuit_action(
            heading_error, ego[..., _GOAL_DIST], ego[..., _SPEED], self.cruise, self.limits
        )
        acc = np.minimum(acc, self.idm_acceleration(f, present))
        acc = np.clip(acc, -self.limits.acc_max, self.limits.acc_max)
        return np.stack([acc / self.limits.acc_max, omega / self.limits.omega_max], -1)


#: The scripted drivers by name, each a factory of its driver ``(features, mask) -> action``.
SCRIPTED = {
    "hold": lambda: HoldDriver(),
    "stop": lambda: StopDriver(),
    "pursuit_3": lambda: PursuitDriver(cruise=3.0),
    "pursuit_5": lambda: PursuitDriver(cruise=5.0),
    "car_aware": lambda: CarAwareDriver(),
}
