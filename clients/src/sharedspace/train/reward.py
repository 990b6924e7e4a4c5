"""Named rewards: the weights a learner's envs are created with, over the world's defaults
(SPEC 8.2 names: progress, success, collision, danger, comfort_jerk, comfort_omega).

- ``world``: the world's own weights (docs/MODEL.md 7: danger 20, collision -20), which the
  paper's SAC-GCN tables were trained with.
- ``learner``: the reward a learner can learn from (docs/MODEL.md 7.1). Under the world's
  weights a car that stands beside a pedestrian who stopped in its path pays the danger term
  every step until the horizon, so the car-aware script's timeouts return less than its
  collisions (crossing task: +1 success, -107 collision, -343 timeout), and a learner that
  maximises return learns to drive into people. ``learner`` cuts danger tenfold, makes a
  collision cost 100 and pays 3 per metre of progress: the script's returns then order
  success > timeout > collision in both worlds (``python benchmarks/script_returns.py``,
  docs/RESULTS.md "The learner reward"). Progress pays 3 because at 1 a learner from scratch
  in Table II-G's crowd, where driving straight on collides in 79 % of the test scenes, learns
  first to stand still (0.3 m/s after 500 000 frames, success 0) and takes millions of frames
  to move again; at 3 it keeps moving (2.4 m/s) while its collisions fall (measured on
  training scenes, results/ppo/runs/tune*).

Success, collision and timeout, what every benchmark counts, never depend on the weights.
"""

from __future__ import annotations

__all__ = ["LEARNER_REWARD", "REWARDS"]

#: The learner reward's weights over the world's.
LEARNER_REWARD: dict[str, float] = {"progress": 3.0, "danger": 2.0, "collision": -100.0}

#: Every named reward: its weights over the world's defaults.
REWARDS: dict[str, dict[str, float]] = {"world": {}, "learner": LEARNER_REWARD}
