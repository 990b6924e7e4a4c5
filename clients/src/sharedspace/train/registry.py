"""Every learning algorithm, registered once by name: what it is (one car or several, on- or
off-policy), its config class (its options and their defaults,
:mod:`sharedspace.train.algorithm_configs`), and the module that implements it.

An algorithm's module has what the one training loop (:mod:`sharedspace.train.loop`) asks of
it: ``make_world(cfg)`` (one car per env, :class:`~sharedspace.train.loop.OneCar`, or the
crossing task's cars, :class:`~sharedspace.marl.train.Cars`) and ``make_learner(cfg, world,
env)`` (its actor and its update per collected batch); a one-car algorithm also has
``make_actor(cfg, action_spec)``, the policy a checkpoint's ``actor`` weights load into. The
module is named by its import path and imported when first used, so that the registry (and the
config that checks names against it) sits below every implementation.

Adding one (docs/ARCHITECTURE.md, "Adding an algorithm")::

    from sharedspace.train.registry import Algorithm, register_algorithm

    register_algorithm(
        Algorithm("my_algo", module="my_package.my_algo", config=MyAlgoConfig, family="on")
    )

after which ``python -m sharedspace.train --set algorithm=my_algo`` runs the one loop over
``my_package.my_algo``'s ``make_world`` and ``make_learner`` (their contract:
:mod:`sharedspace.train.protocol`) and ``python -m sharedspace.bench`` plays its checkpoints.
"""

from __future__ import annotations

import importlib
from dataclasses import dataclass
from types import ModuleType

from sharedspace.cli import UserError, did_you_mean
from sharedspace.train.algorithm_configs import (
    AlgorithmConfig,
    MappoConfig,
    MasacConfig,
    PpoConfig,
    SacConfig,
)

__all__ = [
    "ALGORITHMS",
    "Algorithm",
    "UnknownAlgorithm",
    "algorithm_names",
    "get_algorithm",
    "register_algorithm",
]


class UnknownAlgorithm(UserError):
    """An algorithm name that no registered algorithm has."""


@dataclass(frozen=True, eq=False)
class Algorithm:
    """One registered algorithm."""

    name: str  # what ``--set algorithm=...`` and a checkpoint call it
    module: str | ModuleType  # its implementation (import path, or the module itself)
    cars: str = "one"  # "one": a car per env; "many": the crossing task's cars; "any": either,
    #                    as the task says
    family: str = "off"  # "on" (fresh batches, PPO) or "off" (a replay buffer, SAC)
    #: its config class: its options with their defaults (an option of another algorithm's
    #: class is refused by name)
    config: type[AlgorithmConfig] = AlgorithmConfig
    fused_networks_only: bool = False  # its update is written for the built-in encoders
    centralized_critic: bool = False  # several cars: each car's critic sees every car (MAPPO)
    paper_labels: bool = False  # its rows take the paper's labels (S-SAC, G-SAC-NoCog, ...)
    doc: str = ""  # one line: what it is

    def load(self) -> ModuleType:
        """The implementing module (imported on first use)."""
        if isinstance(self.module, ModuleType):
            return self.module
        return importlib.import_module(self.module)

    @property
    def multi_car(self) -> bool:
        """Several cars only (an algorithm of ``cars="any"`` goes by its task)."""
        return self.cars == "many"

    def drives(self, cars: int) -> bool:
        """Whether it learns in a world of ``cars`` learning cars per scene."""
        return self.cars == "any" or (cars > 1) == (self.cars == "many")


#: Every registered algorithm by name.
ALGORITHMS: dict[str, Algorithm] = {}


def register_algorithm(algorithm: Algorithm) -> Algorithm:
    """Registers ``algorithm``; a name taken by another module is refused."""
    if algorithm.cars not in ("one", "many", "any"):
        raise ValueError(f"algorithm {algorithm.name}: cars must be 'one', 'many' or 'any'")
    if algorithm.family not in ("on", "off"):
        raise ValueError(f"algorithm {algorithm.name}: family must be 'on' or 'off'")
    old = ALGORITHMS.get(algorithm.name)
    if old is not None and old.module != algorithm.module:
        raise ValueError(f"algorithm name {algorithm.name!r} is taken (by {old.module})")
    ALGORITHMS[algorithm.name] = algorithm
    return algorithm


def algorithm_names(cars: str | None = None) -> tuple[str, ...]:
    """The registered names (of ``cars`` "one" or "many" only, if given)."""
    return tuple(n for n, a in ALGORITHMS.items() if cars is None or a.cars in (cars, "any"))


def get_algorithm(name: str, cars: str | None = None) -> Algorithm:
    """The algorithm of ``name``; :class:`UnknownAlgorithm` naming the registered ones (and
    where ``cars`` is given, a clear error for an algorithm of the other kind)."""
    if name not in ALGORITHMS:
        raise UnknownAlgorithm(
            f"algorithm must be one of {', '.join(ALGORITHMS)}; not {name!r}"
            + did_you_mean(name, ALGORITHMS)
        )
    algo = ALGORITHMS[name]
    if cars is not None and algo.cars not in (cars, "any"):
        where = "several cars" if algo.multi_car else "one car"
        raise UnknownAlgorithm(
            f"algorithm {name} learns {where} per env; this world needs one of "
            f"{', '.join(algorithm_names(cars))}"
        )
    return algo


#: The built-in algorithms, each with its config class (its options and their defaults).
register_algorithm(
    Algorithm(
        "sac",
        "sharedspace.train.sac",
        config=SacConfig,
        family="off",
        fused_networks_only=True,
        paper_labels=True,
        doc="the paper's SAC-GCN (Algorithm 2): replay buffer, two critics, learned temperature",
    )
)
register_algorithm(
    Algorithm(
        "ppo",
        "sharedspace.train.ppo",
        config=PpoConfig,
        family="on",
        doc="PPO on wide batches of envs (clipped ratio, GAE), TorchRL's ClipPPOLoss",
    )
)
for _name, _family, _config, _central, _doc in (
    ("mappo", "on", MappoConfig, True, "MAPPO: PPO per car, a critic over every car"),
    ("ippo", "on", MappoConfig, False, "IPPO: PPO per car, each critic over its own car"),
    ("masac", "off", MasacConfig, True, "MASAC: SAC per car, centralised Q-critics"),
):
    register_algorithm(
        Algorithm(
            _name,
            "sharedspace.marl.masac" if _family == "off" else "sharedspace.marl.mappo",
            config=_config,
            cars="many",
            family=_family,
            centralized_critic=_central,
            doc=_doc,
        )
    )
