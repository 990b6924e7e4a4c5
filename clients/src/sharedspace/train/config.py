"""A run's config: the run's own fields and the three parts it composes, built once from flat
``key=value`` words, a TOML/JSON table or a saved config.

- the **world** (:class:`~sharedspace.world_config.WorldConfig`): pool, world parameters,
  ``max_agents``, variations, composed scenes, validation split, server;
- the **algorithm's** (its registered config class, :mod:`sharedspace.train.algorithm_configs`):
  its options with its own defaults;
- the **network** (:class:`~sharedspace.train.networks.NetworkConfig`): the network and its
  sizes.

The command line stays flat: every ``--set`` key belongs to exactly one part and keeps its name
(:func:`part_of`); a checkpoint's ``config`` and ``config.json`` are that flat table
(:meth:`TrainConfig.to_dict`). Building a config writes no file and asks no server.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import tomllib
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from sharedspace.cli import UserError, declared_default, did_you_mean, parse_value
from sharedspace.train.algorithm_configs import (
    AlgorithmConfig,
    AlgorithmConfigError,
    Driving,
    SacConfig,
)
from sharedspace.train.networks import (
    NETWORK_KEYS,
    NetworkConfig,
    NetworkConfigError,
    canonical_network,
    get_network,
)
from sharedspace.train.registry import (
    ALGORITHMS,
    UnknownAlgorithm,
    algorithm_names,
    get_algorithm,
)
from sharedspace.world_config import WorldConfig, WorldConfigError, task_fields
from sharedspace.worlds import TRAINING_TASKS

__all__ = [
    "ConfigError",
    "TrainConfig",
    "apply_overrides",
    "load_config",
    "part_of",
]


class ConfigError(UserError):
    """A config field with a wrong value, or an option of the other algorithm; the message
    names the field."""


class UnknownFieldError(ConfigError, KeyError):
    """A config key that no field has."""

    def __str__(self) -> str:  # KeyError quotes its message
        return str(self.args[0])


#: Fields of older configs, ignored when one is loaded (``env_backend``: the Rust server is
#: the only backend).
RETIRED_FIELDS = ("env_backend",)
#: Fields of older configs under their new names (``variant``: the network is no SAC variant;
#: ``eval_every``: the multi-car learners' own config).
RENAMED_FIELDS = {"variant": "network", "eval_every": "eval_interval"}
#: The values by which configs saved before the per-algorithm configs left a field to the
#: algorithm: a saved field with one of them takes the algorithm's default.
OLD_PLACEHOLDERS: dict[str, Any] = {
    "network": "auto",
    "num_envs": 0,
    "reward": "",
    "eval_interval": -1,
    "base_driver": "auto",
    "residual_scale": 0.0,
    "minibatch_size": 0,
    "ppo_epochs": 0,
    "max_grad_norm": 0.0,
    "utd_ratio": 0.0,
    "buffer_size": 0,
    "alpha_init": 0.0,
    "hidden_sizes": [],
}

WORLD_KEYS = tuple(WorldConfig.__dataclass_fields__)


@dataclass(init=False)
class TrainConfig:
    """Every knob of a run, for any registered algorithm, one car or several: the run's own
    fields (one line of doc each), and its world, algorithm and network parts. Built from flat
    keys, ``TrainConfig(task="crowd", algorithm="ppo", lr=1e-3)``, as the command line gives
    them; a key of another algorithm's options is a :class:`ConfigError` naming it."""

    # --- run
    algorithm: str = "sac"  # a registered algorithm: sac | ppo (one car); mappo | ippo | masac
    seed: int = 0  # seed of torch, numpy and the env's scenario sequence
    total_frames: int = 200_000  # env steps to collect (summed over the K sub-envs)
    device: str = "auto"  # torch device of the networks and updates; auto = cuda if torch sees one
    num_threads: int = 1  # torch CPU threads (0 = torch's default; 1 is fastest on shared cores)
    checkpoint_interval: int = 50_000  # frames between checkpoints (0 = only at the end)
    log_dir: str = "runs/default"  # run directory: metrics.csv, TensorBoard events, checkpoints
    progress: bool = True  # show a tqdm progress bar
    # --- parts
    world: WorldConfig = field(default_factory=WorldConfig)  # the world and its server
    algo: AlgorithmConfig = field(default_factory=SacConfig)  # the algorithm's options
    net: NetworkConfig = field(default_factory=NetworkConfig)  # the network
    #: how the policy drives its envs (its residual over ``base_driver``, its reward weights),
    #: made once from the algorithm's options so that the run never comes back for them
    driving: Driving = field(default_factory=Driving, compare=False, repr=False)
    #: the keys this config was built from, as given (what :func:`apply_overrides` applies over)
    given: dict[str, Any] = field(default_factory=dict, compare=False, repr=False)

    def __init__(self, **fields: Any):
        named = ((_field_name(key), value) for key, value in fields.items())
        given = {key: value for key, value in named if key is not None}  # retired: dropped
        parts = {part: {} for part in ("run", "world", "algo", "net")}
        algorithm = given.get("algorithm", RUN_DEFAULTS["algorithm"])
        try:
            algo = get_algorithm(algorithm)
        except UnknownAlgorithm as err:
            raise ConfigError(str(err)) from None
        for key, value in given.items():
            parts[part_of(key, algorithm)][key] = value
        if algo.multi_car and not parts["world"].get("task"):
            parts["world"]["task"] = "crossing"  # the one task of several learning cars
        try:
            world = WorldConfig(**parts["world"])
            cars = world.cars
            if not algo.drives(cars):
                raise ConfigError(
                    f"task {world.task} has {cars} learning car(s) per scene and algorithm "
                    f"{algorithm} learns {'several' if algo.multi_car else 'one'}: one of "
                    f"{', '.join(algorithm_names('many' if cars > 1 else 'one'))}"
                )
            options = algo.config(**parts["algo"])
            driving = Driving(
                options.base_driver, options.residual_scale, options.world_reward_weights
            )
        except (WorldConfigError, AlgorithmConfigError) as err:
            raise ConfigError(str(err)) from None
        for name, value in (RUN_DEFAULTS | parts["run"]).items():
            setattr(self, name, value)
        if self.device == "auto":
            import torch  # the machine's: imported once a config is made

            self.device = "cuda" if torch.cuda.is_available() else "cpu"
        self.world, self.algo, self.driving, self.given = world, options, driving, given
        self.net = _network_part(parts["net"], algo, cars, world.max_agents, self.device)
        if self.total_frames < 1:
            raise ConfigError(f"total_frames must be at least 1, not {self.total_frames}")

    @property
    def reward_weights(self) -> dict[str, float]:
        """The weights sent with the envs: the named reward's, then ``reward_weights``."""
        return self.driving.reward_weights

    def world_record(self) -> dict[str, Any]:
        """What a checkpoint records of the world it was trained in: the world's record
        (:meth:`WorldConfig.record`) and the reward."""
        reward = {"name": self.algo.reward, "weights": self.reward_weights}
        return self.world.record() | {"reward": reward}

    def to_dict(self) -> dict[str, Any]:
        """The flat table of every key, as ``--set`` names them (``config.json``, a
        checkpoint's ``config``)."""
        run = {name: getattr(self, name) for name in RUN_DEFAULTS}
        net = {name: getattr(self.net, name) for name in NETWORK_KEYS}
        return run | dataclasses.asdict(self.world) | dataclasses.asdict(self.algo) | net

    @classmethod
    def from_dict(cls, fields: dict[str, Any]) -> TrainConfig:
        """A config from a saved one (a checkpoint's, ``config.json``, a multi-car run's own
        config of before the one config): :meth:`saved_fields`."""
        return cls(**cls.saved_fields(fields))

    @classmethod
    def saved_fields(cls, fields: dict[str, Any], algorithm: str | None = None) -> dict[str, Any]:
        """The fields of a saved config as :meth:`from_dict` takes them (for ``algorithm``, if
        given, rather than the saved one's): renamed fields under their names; retired ones,
        the options of other algorithms (older configs held every option), the old
        placeholders and the values its task filled in dropped (so that an override of the
        task fills them in anew); for another algorithm, the saved algorithm's defaults too."""
        fields = {RENAMED_FIELDS.get(k, k): v for k, v in fields.items() if k not in RETIRED_FIELDS}
        saved_algorithm = fields.get("algorithm", RUN_DEFAULTS["algorithm"])
        fields["algorithm"] = algorithm or saved_algorithm
        fields.pop("eval_envs", None)  # configs before the validation split
        if "hidden" in fields or "depth" in fields:  # the multi-car config's MLP
            hidden, depth = fields.pop("hidden", 128), fields.pop("depth", 2)
            fields["hidden_sizes"] = [int(hidden)] * int(depth)
        try:
            algo = get_algorithm(fields["algorithm"])
        except UnknownAlgorithm as err:
            raise ConfigError(str(err)) from None
        old_batch = "rollout_steps" not in fields and fields.get("frames_per_batch")
        if algo.family == "on" and algo.multi_car and old_batch:  # the multi-car config's
            num_envs = int(fields.get("num_envs") or algo.config.num_envs)
            fields["rollout_steps"] = int(fields["frames_per_batch"]) // num_envs
        mine = set(RUN_DEFAULTS) | set(WORLD_KEYS) | set(NETWORK_KEYS) | set(algo.config.options())
        out = {k: v for k, v in fields.items() if k in mine}
        out = {k: v for k, v in out.items() if OLD_PLACEHOLDERS.get(k, _NONE) != v}
        if out.get("task") in TRAINING_TASKS:  # what the task filled in: the task's again
            filled = task_fields(out["task"])
            out = {k: v for k, v in out.items() if filled.get(k, _NONE) != v}
        if saved_algorithm != out["algorithm"] and saved_algorithm in ALGORITHMS:
            theirs = get_algorithm(saved_algorithm).config
            for name in set(theirs.options()) & set(out):
                if out[name] == declared_default(theirs, name):
                    del out[name]  # the saved algorithm's default: the new one's
            if out.get("network") == theirs.default_network:
                del out["network"]
        return out


_NONE = object()

#: The run's own fields and their defaults.
RUN_DEFAULTS: dict[str, Any] = {
    f.name: f.default
    for f in dataclasses.fields(TrainConfig)
    if f.default is not dataclasses.MISSING
}


def part_of(key: str, algorithm: str) -> str:
    """The part of a run of ``algorithm`` the key ``key`` belongs to: ``run``, ``world``,
    ``algo`` or ``net``; an option of another algorithm is a :class:`ConfigError` naming the
    algorithms that have it."""
    if key in RUN_DEFAULTS:
        return "run"
    if key in WORLD_KEYS:
        return "world"
    if key in NETWORK_KEYS:
        return "net"
    if key in get_algorithm(algorithm).config.options():
        return "algo"
    owners = [a.name for a in ALGORITHMS.values() if key in a.config.options()]
    raise ConfigError(
        f"{key} is an option of algorithm={'|'.join(owners)}, and this config's algorithm is "
        f"{algorithm}"
    )


def all_keys() -> dict[str, Any]:
    """Every ``--set`` key of any algorithm, with a default it may take (the run's, the
    world's, the network's, or the first algorithm's that has it): what a value is parsed
    like."""
    out: dict[str, Any] = dict(RUN_DEFAULTS)
    out |= {k: declared_default(WorldConfig, k) for k in WORLD_KEYS}
    out |= {k: declared_default(NetworkConfig, k) for k in NETWORK_KEYS}
    for algo in ALGORITHMS.values():
        for name in algo.config.options():
            out.setdefault(name, declared_default(algo.config, name))
    return out


def _network_part(
    given: dict[str, Any], algo, cars: int, max_agents: int, device: str
) -> NetworkConfig:
    """The network part: the given keys over the algorithm's network; a network of several
    cars may be "" (each car's nodes flattened into its MLP)."""
    network = given.get("network", algo.config.default_network)
    try:
        if network or cars == 1:
            network = canonical_network(network)
        net = NetworkConfig(**(given | {"network": network}), max_agents=max_agents, device=device)
    except NetworkConfigError as err:
        raise ConfigError(str(err)) from None
    if algo.fused_networks_only and (not net.network or not get_network(net.network).fused_sac):
        raise ConfigError(
            f"network {net.network}: algorithm {algo.name}'s fused update knows the built-in "
            "encoders only (gcn_risk, gcn_uniform, mlp)"
        )
    return net


def apply_overrides(cfg: TrainConfig, overrides: list[str] | dict[str, Any]) -> TrainConfig:
    """A new config: the keys ``cfg`` was built from (:attr:`TrainConfig.given`) with
    ``key=value`` strings (or a dict) applied over them; string values are parsed by the key's
    type (:func:`parse_value`), as the command line's :func:`load_config` parses them."""
    data = dict(cfg.given)
    current = cfg.to_dict()
    items = (
        overrides.items() if isinstance(overrides, dict) else (o.split("=", 1) for o in overrides)
    )
    for item in items:
        if len(item) != 2:
            raise ConfigError(f"--set {item[0]!r}: expected KEY=VALUE")
        key, value = _field_name(item[0].strip()), item[1]
        if key is None:  # a retired field
            continue
        if isinstance(value, str):
            value = parse_value(key, value, current.get(key, all_keys()[key]), ConfigError)
        data[key] = value
    return TrainConfig(**data)  # strict: an option of another algorithm is named, not dropped


def command_parser(prog: str, doc: str | None) -> argparse.ArgumentParser:
    """The argument parser of a ``python -m`` command: its module docstring ``doc`` as the
    description, printed as written."""
    return argparse.ArgumentParser(
        prog=prog, description=doc, formatter_class=argparse.RawDescriptionHelpFormatter
    )


def add_overrides_argument(
    ap, help: str = "TrainConfig overrides, e.g. server_endpoint=..."
) -> None:
    """The ``--set KEY=VALUE ...`` option every ``sharedspace.train`` command takes (repeatable;
    values parsed like the field they override)."""
    ap.add_argument("--set", nargs="*", action="extend", default=[], metavar="KEY=VALUE", help=help)


def load_config(
    path: str | Path | None = None,
    overrides: Sequence[str] | None = None,
    *,
    saved: dict[str, Any] | None = None,
    default_algorithm: str = "",
) -> TrainConfig:
    """The command line's config, built once: the defaults, then ``saved`` (a checkpoint's
    config, when resuming: :meth:`TrainConfig.saved_fields`), then the TOML/JSON file at
    ``path`` (a flat table of fields), then the ``key=value`` ``overrides``, each over the one
    before. A new run whose words name no algorithm takes ``default_algorithm`` (``python -m
    sharedspace.marl``: mappo), else the config's default. An unknown key is a
    :class:`UnknownFieldError`; an option of another algorithm than the one chosen is a
    :class:`ConfigError` naming it."""
    given = _given_fields(_read_table(path)) if path else {}
    for key, text in _split_overrides(overrides or []):
        like = given.get(key, (saved or {}).get(key, all_keys()[key]))
        given[key] = parse_value(key, text, like, ConfigError)
    algorithm = given.get("algorithm") or (
        None if saved is not None else default_algorithm or RUN_DEFAULTS["algorithm"]
    )
    base = TrainConfig.saved_fields(saved, algorithm) if saved is not None else {}
    return TrainConfig(**(base | {"algorithm": algorithm or base["algorithm"]} | given))


def _given_fields(table: dict[str, Any]) -> dict[str, Any]:
    """A user's table of fields under their fields' names (:func:`_field_name`)."""
    named = ((_field_name(key), value) for key, value in table.items())
    return {key: value for key, value in named if key is not None}


def _split_overrides(overrides: Sequence[str]) -> list[tuple[str, str]]:
    """``KEY=VALUE`` words as (field, text) pairs (:func:`_field_name`); a malformed word
    refused."""
    out = []
    for word in overrides:
        item = word.split("=", 1)
        if len(item) != 2:
            raise ConfigError(f"--set {item[0]!r}: expected KEY=VALUE")
        key = _field_name(item[0].strip())
        if key is not None:
            out.append((key, item[1]))
    return out


def _field_name(key: str) -> str | None:
    """``key`` as a key of :class:`TrainConfig` (:func:`all_keys`): a renamed field under its
    new name, None for a retired one; an unknown key is an :class:`UnknownFieldError`."""
    key = RENAMED_FIELDS.get(key, key)
    if key in RETIRED_FIELDS:
        return None
    known = all_keys()
    if key not in known:
        raise UnknownFieldError(
            f"unknown config key {key!r}{did_you_mean(key, known)}; "
            "`python -m sharedspace.train --help` lists every key"
        )
    return key


def _read_table(path: str | Path) -> dict[str, Any]:
    p = Path(path)
    return tomllib.loads(p.read_text()) if p.suffix == ".toml" else json.loads(p.read_text())
