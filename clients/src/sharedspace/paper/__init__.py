"""The paper's tooling, on the trainer (:mod:`sharedspace.train`) and the envs:

- :mod:`.evaluate`: Table II on a split, a checkpoint or a scripted driver, the human row
  (``python -m sharedspace.paper.evaluate``);
- :mod:`.powered`: the powered test, paired on seeded variations of every test scene;
- :mod:`.table2`: the Table II runs, trained, evaluated and rendered;
- :mod:`.planner`: the open-loop search, the planner bound;
- :mod:`.drivers`: the scripted reference drivers (``pursuit_3``, ``hold``, ...);
- :mod:`.episode`: one episode as pictures, a GIF or an MP4;
- :mod:`.plots`: learning curves, speed/acceleration/heading profiles, risk-graph scenes;
- :mod:`.pools`: the derived scenario pools (validation split, paper plus general).
"""
