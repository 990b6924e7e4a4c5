"""Several learning cars in one scene (issue 41).

- :mod:`.task`: the crossing task;
- :mod:`.evaluate`: its per-car evaluation;
- :mod:`.bound`: the planner's bound per car;
- :mod:`.networks`: each car's observation, the shared policy, the critics' MLP;
- :mod:`.mappo` (MAPPO, IPPO), :mod:`.masac`: one algorithm each, on TorchRL's multi-agent
  modules and losses;
- :mod:`.train`: the loop over them (``python -m sharedspace.marl``).
"""
