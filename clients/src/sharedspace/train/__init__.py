"""SAC(-GCN) trainer, baselines and evaluation of the AV policy (paper Section IV.C, Table II).

- :mod:`.config`: :class:`TrainConfig` (TOML/JSON + ``key=value`` overrides);
- :mod:`.gcn`: masked GCN encoders of the three variants (``g_sac_cog``, ``g_sac_nocog``,
  ``s_sac``);
- :mod:`.sac`: builders (env, actor, critic, loss, optimisers, replay buffer, collector);
- :mod:`.train`: the training loop (``python -m sharedspace.train``);
- :mod:`.evaluate`: Table II on a split (``python -m sharedspace.train.evaluate``);
- :mod:`.plots`: learning curves, speed/acceleration/heading profiles, risk-graph scenes.
"""

from sharedspace.train.config import VARIANTS, TrainConfig, load_config

__all__ = ["VARIANTS", "TrainConfig", "load_config"]
