"""The frozen adversarial stress test of the drivers, ``crowd-adversary`` (docs/MODEL.md 2c).

The task is the ``crowd`` task (Table II-G's 76 test scenes x 4 seeded variations, its world,
its reacting cars) with one pedestrian per scene given to an adversary:

- **who:** of the scene's pedestrians present from its first step, the one whose recorded
  path comes nearest the car's recorded path at the same step. The task's pool is the crowd
  pool with that pedestrian moved first among the pedestrians, so it is ``pedestrian_0``
  (:func:`adversary_pool`); the driver is ``vehicle_0``, the recorded car.
- **held to plausible walking:** its commanded acceleration and its speed stay within the range
  the CR-SFM pedestrians of the crowd world walk in (:data:`WALKING_RANGE`, their 99th
  percentiles over the train scenes: ``python -m sharedspace.adversary walking-range``);
  :func:`plausible_action` projects any action into it.
- **rewarded** (:data:`ADVERSARY_REWARD`, weights by name): ``fault`` when the driver's
  collision with it is the driver's fault (the server's ``at_fault`` event), ``blame`` when it
  touches a vehicle that is not at fault (its side or rear, or stepping in nearer than the
  vehicle's braking distance), ``approach`` per metre it closes on the driver, ``ahead`` per
  step the driver sees it in the corridor ahead of it (15 m long, 3 m wide): the last two shape
  the search, the fault itself is the server's judgement (docs/MODEL.md 2c).

The pool file is derived from ``crowd``'s and checked by its fingerprint, like every task's.
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from sharedspace.bench.tasks import REPO, Task, get_task, scenes_fingerprint, versioned

__all__ = [
    "ADVERSARY_REWARD",
    "AdversaryTask",
    "WALKING_RANGE",
    "adversary_pool",
    "get_adversary_task",
    "plausible_action",
]

#: The CR-SFM pedestrians' walking range in the crowd world: the 95th percentiles of their
#: speed (m/s) and of their acceleration's norm (m/s², ``|v_t - v_{t-1}| / dt``) over every
#: step of the 229 train scenes, variation seed 0, the car replayed (``python -m
#: sharedspace.adversary walking-range``, 2026-12-07; 66 770 speeds). The 99th (2.0 m/s, the
#: model's cap, and 3.6 m/s²) are fleeing a car, not walking.
WALKING_RANGE = {"speed_max": 1.693, "acc_max": 1.6}

#: The adversary's reward terms and their weights (``reward_weights`` overrides them by name).
ADVERSARY_REWARD = {"fault": 10.0, "blame": -5.0, "approach": 0.2, "ahead": 0.05}


@dataclass(frozen=True)
class AdversaryTask:
    """A frozen adversarial task over a driving task; every field decides its score."""

    name: str
    version: int
    description: str
    base: str  # the driving task whose scenes, variations and world it plays
    pool: str  # the derived pool file, relative to the repository
    scenes_sha256: str  # fingerprint of the derived pool's test scenes
    walking_range: dict[str, float] = field(default_factory=lambda: dict(WALKING_RANGE))
    reward: dict[str, float] = field(default_factory=lambda: dict(ADVERSARY_REWARD))

    def __hash__(self) -> int:
        return hash((self.name, self.version))

    @property
    def tag(self) -> str:
        return f"{self.name}@{self.version}"

    @property
    def driving(self) -> Task:
        """The driving task it stresses (scenes, variations, world, ``max_agents``)."""
        return get_task(self.base)

    def fingerprint(self) -> str:
        fields = {f.name: getattr(self, f.name) for f in dataclasses.fields(self)}
        fields.pop("description")
        fields["base"] = self.driving.fingerprint()
        blob = json.dumps(fields, sort_keys=True, separators=(",", ":")).encode()
        return hashlib.sha256(blob).hexdigest()[:16]

    def pool_path(self) -> Path:
        """The derived pool, written from the driving task's pool where missing, and checked."""
        path = REPO / self.pool
        if not path.is_file():
            derived = adversary_pool(json.loads(self.driving.pool_path().read_text()))
            path.parent.mkdir(parents=True, exist_ok=True)
            path.write_text(json.dumps(derived))
        scenes = [s for s in json.loads(path.read_text())["scenarios"] if s["split"] == "test"]
        if scenes_fingerprint(scenes) != self.scenes_sha256:
            raise ValueError(
                f"task {self.tag}: {self.pool} is not the task's pool (its test scenes' "
                "fingerprint differs); delete it to derive it again"
            )
        return path


def adversary_pool(pool: dict[str, Any]) -> dict[str, Any]:
    """``pool`` with each scene's adversary moved first among its pedestrians (so that it is
    ``pedestrian_0``): of the pedestrians present from the scene's first step, the one whose
    recorded position comes nearest the car's (the scene's ``ego``) at the same step."""
    out = dict(pool, name=pool["name"] + "-adversary", scenarios=[])
    for scene in pool["scenarios"]:
        agents = list(scene["agents"])
        ego = agents[scene.get("ego", 0)]
        first_ped = next(i for i, a in enumerate(agents) if a["kind"] == "pedestrian")
        best = min(
            (i for i, a in enumerate(agents) if a["kind"] == "pedestrian" and a["start_step"] == 0),
            key=lambda i: _nearest_approach(ego, agents[i]),
        )
        agents.insert(first_ped, agents.pop(best))
        ego_index = agents.index(ego)
        out["scenarios"].append(dict(scene, agents=agents, ego=ego_index))
    return out


def _nearest_approach(car: dict[str, Any], ped: dict[str, Any]) -> float:
    """The least distance between two records at the same step (infinite if never together)."""
    t0 = max(car["start_step"], ped["start_step"])
    t1 = min(car["start_step"] + len(car["positions"]), ped["start_step"] + len(ped["positions"]))
    if t1 <= t0:
        return math.inf
    c = np.asarray(car["positions"][t0 - car["start_step"] : t1 - car["start_step"]])
    p = np.asarray(ped["positions"][t0 - ped["start_step"] : t1 - ped["start_step"]])
    return float(np.min(np.linalg.norm(c - p, axis=1)))


def plausible_action(
    action: np.ndarray, speed: np.ndarray, dt: float, ped_acc_max: float, walking: dict
) -> np.ndarray:
    """The server action (``[K, 2]``, model.md 2b) of the adversary's command ``action``
    (``[K, 2]`` in ``[-1, 1]``: an acceleration along and to the left of its heading, as a
    fraction of ``walking["acc_max"]``) for pedestrians walking at ``speed`` (``[K]``, m/s,
    along their heading): the acceleration's norm capped at ``acc_max``, then shortened so that
    the speed it reaches stays at most ``walking["speed_max"]``."""
    a_max, v_max = walking["acc_max"], walking["speed_max"]
    acc = np.clip(np.asarray(action, dtype=np.float64), -1.0, 1.0) * a_max
    norm = np.linalg.norm(acc, axis=1, keepdims=True)
    acc = np.where(norm > a_max, acc * (a_max / np.maximum(norm, 1e-12)), acc)
    v_new = np.stack([speed, np.zeros_like(speed)], axis=1) + acc * dt
    v_norm = np.linalg.norm(v_new, axis=1, keepdims=True)
    capped = np.where(v_norm > v_max, v_new * (v_max / np.maximum(v_norm, 1e-12)), v_new)
    acc = (capped - np.stack([speed, np.zeros_like(speed)], axis=1)) / dt
    return np.clip(acc / ped_acc_max, -1.0, 1.0).astype(np.float32)


#: The adversarial tasks by name.
ADVERSARY_TASKS = {
    "crowd-adversary": AdversaryTask(
        name="crowd-adversary",
        version=1,
        description="crowd's 76 test scenes x 4 variations, the pedestrian nearest the car's "
        "path an adversary of the driver",
        base="crowd",
        pool="out/adversary/pool-crowd-adversary.json",
        scenes_sha256="9d09b29255af0d9d11e06ead057100bd6ce121c5f33572a31c52c71800f9ed6a",
    ),
}


def get_adversary_task(name: str = "crowd-adversary") -> AdversaryTask:
    """The adversarial task of that name (``name@version`` checks the version too)."""
    return versioned(name, ADVERSARY_TASKS, ValueError)
