"""The learners (paper Section IV.C, and PPO): read :mod:`.sac` or :mod:`.ppo` top to bottom.

- :mod:`.config`: :class:`TrainConfig`, a run's fields and its world, algorithm and network
  parts (:mod:`sharedspace.world_config`, :mod:`.algorithm_configs`, :mod:`.networks`), and
  the one ``--set`` grammar;
- :mod:`.reward`: the named rewards (``world``, ``learner``);
- :mod:`.envs`: the batched env of a world and the residual transform;
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

import importlib

#: What the package exports, by the module that holds it: imported on first use, so that
#: ``python -m sharedspace.train --help`` answers without loading torch.
_EXPORTS = {
    "TrainConfig": "config",
    "load_config": "config",
    "NETWORKS": "networks",
    "Network": "networks",
    "register_network": "networks",
    "ALGORITHMS": "registry",
    "Algorithm": "registry",
    "register_algorithm": "registry",
}


def __getattr__(name: str):
    if name in _EXPORTS:
        return getattr(importlib.import_module(f"{__name__}.{_EXPORTS[name]}"), name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


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
