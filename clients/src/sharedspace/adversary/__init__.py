"""An adversarial stress test of the drivers (``crowd-adversary``, docs/MODEL.md 2c): one
pedestrian per scene driven by a learner that is rewarded for the driver's at-fault
collisions, held to the CR-SFM pedestrians' walking range.

- :mod:`~sharedspace.adversary.task`: the frozen task, its pool, the walking range and reward;
- :mod:`~sharedspace.adversary.env`: the adversary's batched TorchRL env, the driver inside;
- :mod:`~sharedspace.adversary.train`: training an adversary against a named driver;
- :mod:`~sharedspace.adversary.scripted`: hand-written adversaries (``intercept``);
- :mod:`~sharedspace.adversary.stress`: scoring drivers against CR-SFM and the adversaries;
- :mod:`~sharedspace.adversary.compare`: two drivers' scorings side by side, paired.

``python -m sharedspace.adversary --help`` lists the commands.
"""
