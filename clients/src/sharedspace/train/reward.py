"""Named rewards: the weights a learner's envs are created with, over the world's defaults
(SPEC 8.2 names: progress, success, collision, danger, comfort_jerk, comfort_omega).

- ``world``: the world's own weights (docs/MODEL.md 7: danger 20, collision -20), which the
  paper's SAC-GCN tables were trained with.
- ``learner``: the reward a learner can learn from (docs/MODEL.md 7.1). Under the world's
  weights a car that stands beside a pedestrian who stopped in its path pays the danger term
  every step until the horizon, so the car-aware script's timeouts return less than its
  collisions (crossing task: +1 success, -107 collision, -343 timeout), and a learner that
  maximises return learns to drive into people. ``learner`` cuts danger tenfold and makes a
  collision cost 100: the script's returns then order success > timeout > collision in both
  worlds (``python bench/script_returns.py``, docs/RESULTS.md "The learner reward").

Success, collision and timeout, what every benchmark counts, never depend on the weights.
"""

from __future__ import annotations

__all__ = ["LEARNER_REWARD", "REWARDS"]

#: The learner reward's weights over the world's.
LEARNER_REWARD: dict[str, float] = {"danger": 2.0, "collision": -100.0}

#: Every named reward: its weights over the world's defaults.
REWARDS: dict[str, dict[str, float]] = {"world": {}, "learner": LEARNER_REWARD}
