"""Scripted adversaries: hand-written pedestrians that try to make a driver fault, beside the
learned ones, so that a stress test does not rest on what PPO happened to find.

``intercept`` is the jaywalker: it waits beside the driver's path and, within the walking
range, steps into it where the driver could still stop short of it, and stands there
(docs/RESULTS.md, "Adversarial stress test"). A driver who then drives on into it is at fault
(docs/MODEL.md 2c); one who brakes loses time. Against ``hold``, a driver that never brakes,
it shows how often the task lets a fault be made at all.

A scripted adversary is a module over the adversary's observation (the env's tensordict:
``features [K, M, F]``, ``mask [K, M]``) that writes ``action`` (``[K, 2]`` in ``[-1, 1]``,
:func:`~sharedspace.adversary.task.plausible_action`), as a learned one's actor does.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
import torch
from tensordict import TensorDictBase
from torch import nn

from sharedspace.names import Feature
from sharedspace.scripted import VehicleLimits

__all__ = ["SCRIPTED_ADVERSARIES", "Intercept"]


class Intercept(nn.Module):
    """Waits beside the driver's path and steps into it while the driver can still stop.

    The driver is taken to be the nearest vehicle the adversary sees (node order is clearance
    order, SPEC 7). With the driver at ``c``, heading ``f`` and speed ``s``:

    - in the driver's path band (model.md 2c), it brakes to a stand;
    - else it walks, within the walking range, to the nearest point of the path ``d`` ahead of
      the driver's centre, ``inside`` m within the band on its own side (``d`` in steps of
      ``step`` m, up to ``reach`` m), that it reaches while the gap from the driver's
      front to it, less the distance the driver covers meanwhile, is still at least the
      braking distance ``s^2 / (2 b)`` plus ``spare``;
    - with no such point, and while it is ahead of the driver, it waits at the kerb: ``kerb`` m
      outside the path band, level with where it stands;
    - beside or behind the driver, or with no driver in sight, it stands.

    Args:
        walking: the task's walking range (``speed_max`` m/s, ``acc_max`` m/s^2); the action is
            an acceleration as a fraction of ``acc_max``.
        dt: the world's step, s.
        half_length, half_width: the driver's footprint (model.md 2c: 4.0 x 1.8 m), m.
        limits: the driver's limits; its braking ``b`` is their ``acc_max`` (model.md 2c).
        spare: distance kept beyond the braking distance when stepping in, m.
        kerb: how far outside the path band it waits, m.
        inside: how far inside the path band it stands, m.
        step, reach: the points tried along the path, m ahead of the driver's centre.
    """

    def __init__(
        self,
        walking: dict[str, float],
        dt: float = VehicleLimits.dt,
        half_length: float = 2.0,
        half_width: float = 0.9,
        limits: VehicleLimits = VehicleLimits(),  # noqa: B008 - frozen dataclass
        spare: float = 0.5,
        kerb: float = 0.5,
        inside: float = 0.4,
        step: float = 1.0,
        reach: float = 30.0,
    ):
        super().__init__()
        self.speed_max, self.acc_max = float(walking["speed_max"]), float(walking["acc_max"])
        self.dt, self.half_length, self.half_width = dt, half_length, half_width
        self.braking, self.spare, self.kerb, self.inside = limits.acc_max, spare, kerb, inside
        self.distances = np.arange(half_length + 1.0, reach + step / 2, step)

    def forward(self, td: TensorDictBase) -> TensorDictBase:
        f = td.get("features").detach().cpu().numpy().astype(np.float64)
        present = td.get("mask").detach().cpu().numpy().astype(bool)
        action = np.stack([self._act(f[k], present[k]) for k in range(f.shape[0])])
        return td.set("action", torch.as_tensor(action, dtype=torch.float32))

    def _act(self, f: np.ndarray, present: np.ndarray) -> np.ndarray:
        """One adversary's action from its nodes ``f [M, F]`` (its own frame)."""
        velocity = np.array([f[0, Feature.SPEED], 0.0])  # along its heading, by definition
        cars = np.flatnonzero(present & (f[:, Feature.IS_VEHICLE] > 0.5))
        cars = cars[cars > 0]
        if cars.size == 0:
            return self._towards(velocity, np.zeros(2))
        radius, car = f[0, Feature.RADIUS], f[cars[0]]
        centre = np.array([car[Feature.REL_X], car[Feature.REL_Y]])
        forward = np.array([np.cos(car[Feature.HEADING_DIFF]), np.sin(car[Feature.HEADING_DIFF])])
        left = np.array([-forward[1], forward[0]])
        speed = car[Feature.SPEED]
        stopping = speed**2 / (2.0 * self.braking)
        ahead, across = -centre @ forward, -centre @ left  # its place in the driver's frame
        band = self.half_width + radius
        if ahead <= self.half_length + radius or abs(across) < band:
            return self._towards(velocity, np.zeros(2))  # beside, behind, or in the path
        # The stand points: just inside the band, on its side of the path.
        inside = np.sign(across) * max(band - self.inside, 0.0) * left
        points = centre + self.distances[:, None] * forward + inside
        # Time to get there: the distance at full speed, plus the time lost speeding up from
        # its speed towards the point.
        distance = np.linalg.norm(points, axis=1)
        towards = points @ velocity / np.maximum(distance, 1e-9)
        lost = np.clip(self.speed_max - towards, 0.0, None) ** 2 / (2 * self.acc_max)
        arrive = (distance + lost) / self.speed_max
        room = self.distances - self.half_length - radius - speed * arrive
        ok = np.flatnonzero(room >= stopping + self.spare)
        if ok.size:
            target = points[ok[0]]
        else:
            target = centre + ahead * forward + np.sign(across) * (band + self.kerb) * left
        return self._arrive(velocity, target)

    def _arrive(self, velocity: np.ndarray, target: np.ndarray) -> np.ndarray:
        """Towards ``target`` at full speed until it can stop there, then slowing to it."""
        distance = float(np.linalg.norm(target))
        wanted = min(self.speed_max, np.sqrt(2.0 * self.acc_max * distance))
        return self._towards(velocity, target / max(distance, 1e-9) * wanted)

    def _towards(self, velocity: np.ndarray, desired: np.ndarray) -> np.ndarray:
        """The command that changes ``velocity`` to ``desired`` in one step, within
        ``acc_max``."""
        acc = (desired - velocity) / self.dt
        norm = float(np.linalg.norm(acc))
        if norm > self.acc_max:
            acc *= self.acc_max / norm
        return acc / self.acc_max


#: The scripted adversaries by name, each a factory of its module from the task's walking
#: range and the world's step.
SCRIPTED_ADVERSARIES: dict[str, Callable[[dict[str, float], float], nn.Module]] = {
    "intercept": lambda walking, dt: Intercept(walking, dt),
}
