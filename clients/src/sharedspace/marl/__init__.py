"""Several learning cars in one scene (issue 41).

- :mod:`.task`: the crossing task;
- :mod:`.evaluate`: its per-car evaluation;
- :mod:`.bound`: the planner's bound per car;
- :mod:`.train`: MAPPO, IPPO and MASAC on TorchRL's multi-agent modules and losses
  (``python -m sharedspace.marl``).
"""
