"""The SAC-GCN trainer (paper Section IV.C): read :mod:`.train` top to bottom.

- :mod:`.config`: :class:`TrainConfig`, one field a knob (TOML/JSON + ``key=value`` overrides);
- :mod:`.gcn`: the networks, masked GCN encoders of the three variants (``g_sac_cog``,
  ``g_sac_nocog``, ``s_sac``);
- :mod:`.update`: the loss and the gradient step (critics, actor, temperature);
- :mod:`.sac`: the ``make_*`` factories (env, actor, critics, learner, buffer, collector);
- :mod:`.evaluation`: every scenario of a split played once, a checkpoint's actor;
- :mod:`.train`: the loop (``python -m sharedspace.train``).

The tables, the powered test, the planner and the plots are the paper's tooling:
:mod:`sharedspace.paper`.
"""

from sharedspace.train.config import VARIANTS, TrainConfig, load_config

__all__ = ["VARIANTS", "TrainConfig", "load_config"]
