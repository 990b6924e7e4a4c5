"""The learners (paper Section IV.C, and PPO): read :mod:`.sac` or :mod:`.ppo` top to bottom.

- :mod:`.config`: :class:`TrainConfig`, one field a knob, and the one ``--set`` grammar;
- :mod:`.reward`: the named rewards (``world``, ``learner``);
- :mod:`.envs`: the batched env of a config and the residual transform;
- :mod:`.gcn`, :mod:`.policy`: the networks of the three variants and the tanh-normal actor;
- :mod:`.sac` (with :mod:`.update`, :mod:`.prior`) and :mod:`.ppo`: one algorithm each;
- :mod:`.metrics`, :mod:`.checkpoint`, :mod:`.run`: logging, the checkpoint format, the run
  directory and schedule;
- :mod:`.evaluation`: every scenario of a split played once;
- :mod:`.learners`: the algorithms by name, a checkpoint's actor;
- :mod:`.train`: ``python -m sharedspace.train``.

The tables, the powered test, the planner and the plots are the paper's tooling:
:mod:`sharedspace.paper`; several learning cars: :mod:`sharedspace.marl`.
"""

from sharedspace.train.config import VARIANTS, TrainConfig, load_config

__all__ = ["VARIANTS", "TrainConfig", "load_config"]
