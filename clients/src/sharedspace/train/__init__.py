"""The learners (paper Section IV.C, and PPO): read :mod:`.sac` or :mod:`.ppo` top to bottom.

- :mod:`.config`: :class:`TrainConfig`, one field a knob, and the one ``--set`` grammar;
- :mod:`.reward`: the named rewards (``world``, ``learner``);
- :mod:`.envs`: the batched env of a config and the residual transform;
- :mod:`.registry`, :mod:`.networks`: every algorithm and every network, registered once;
- :mod:`.gcn`, :mod:`.policy`: the graph encoders and the tanh-normal actor;
- :mod:`.sac` (with :mod:`.update`, :mod:`.prior`) and :mod:`.ppo`: one algorithm each;
- :mod:`.metrics`, :mod:`.checkpoint`, :mod:`.run`: logging, the checkpoint format, the run
  directory and schedule;
- :mod:`.evaluation`: every scenario of a split played once;
- :mod:`.learners`: a checkpoint's actor, with no server;
- :mod:`.train`: ``python -m sharedspace.train``.

The tables, the powered test, the planner and the plots are the paper's tooling:
:mod:`sharedspace.paper`; several learning cars: :mod:`sharedspace.marl`.
"""

from sharedspace.train.config import TrainConfig, load_config
from sharedspace.train.networks import NETWORKS, Network, register_network
from sharedspace.train.registry import ALGORITHMS, Algorithm, register_algorithm

__all__ = [
    "ALGORITHMS",
    "NETWORKS",
    "Algorithm",
    "Network",
    "TrainConfig",
    "load_config",
    "register_algorithm",
    "register_network",
]
