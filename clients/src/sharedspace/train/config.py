"""Training configuration: one dataclass, loadable from TOML/JSON plus ``key=value`` overrides."""

from __future__ import annotations

import argparse
import copy
import dataclasses
import json
import tomllib
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from sharedspace.cli import UserError, did_you_mean
from sharedspace.client import Connection
from sharedspace.models import DEFAULT_MODEL
from sharedspace.pool import load_pool, split_indices
from sharedspace.train.networks import (
    NetworkConfig,
    UnknownNetwork,
    canonical_network,
    get_network,
)
from sharedspace.train.registry import (
    ALGORITHMS,
    UnknownAlgorithm,
    algorithm_names,
    get_algorithm,
)
from sharedspace.train.reward import REWARDS
from sharedspace.wire import ComposedScenes, EnvSpec
from sharedspace.worlds import (
    UnknownTask,
    held_out_scenes,
    training_task,
    world_params_file,
)

__all__ = [
    "ConfigError",
    "check_algorithm_options",
    "TrainConfig",
    "apply_overrides",
    "load_config",
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
#: Fields left to the algorithm, with the value that says so: the registry's
#: ``Algorithm.defaults`` fill them in, else :data:`BASE_DEFAULTS`.
AUTO_FIELDS: dict[str, Any] = {
    "network": "auto",
    "num_envs": 0,
    "reward": "",
    "eval_interval": -1,
    "base_driver": "auto",
    "residual_scale": 0.0,
    "minibatch_size": 0,
    "ppo_epochs": 0,
    "max_grad_norm": 0.0,
    "frames_per_batch": 0,
    "utd_ratio": 0.0,
    "buffer_size": 0,
    "alpha_init": 0.0,
    "hidden_sizes": [],
}
#: The values of :data:`AUTO_FIELDS` for an algorithm whose registry entry names none (SAC's).
BASE_DEFAULTS: dict[str, Any] = {
    "network": "gcn_risk",
    "num_envs": 8,
    "reward": "world",
    "eval_interval": 20_000,
    "base_driver": "",
    "residual_scale": 1.0,
    "minibatch_size": 2048,
    "ppo_epochs": 4,
    "max_grad_norm": 0.5,
    "utd_ratio": 0.5,
    "buffer_size": 200_000,
    "alpha_init": 1.0,
    "hidden_sizes": [256, 256],
}


#: Fields a task sets by default that a run may set otherwise: how it trains and validates,
#: not the world its policy is scored in.
TRAINING_CHOICES = ("variations", "validation_scenes", "validation_variations")


@dataclass
class TrainConfig:
    """Every knob of a run, for any registered algorithm, one car or several. One line of doc
    per field; a field marked "the algorithm's" is filled in from the registry
    (:data:`AUTO_FIELDS`, :mod:`sharedspace.train.registry`)."""

    # --- run
    algorithm: str = "sac"  # a registered algorithm: sac | ppo (one car); mappo | ippo | masac
    task: str = ""  # train for a benchmark task: paper | crowd (one car) | crossing (several)
    seed: int = 0  # seed of torch, numpy and the env's scenario sequence
    network: str = "auto"  # a registered network: gcn_risk (GCN on the risk graph) |
    #                        gcn_uniform (GCN, uniform graph) | mlp (no graph); "" = each
    #                        car's nodes flattened into its MLP (several cars); auto = the
    #                        algorithm's (gcn_risk; several cars "")
    total_frames: int = 200_000  # env steps to collect (summed over the K sub-envs)
    device: str = "auto"  # torch device of the networks and updates; auto = cuda if torch sees one
    num_threads: int = 1  # torch CPU threads (0 = torch's default; 1 is fastest on shared cores)
    # --- env
    num_envs: int = 0  # K, sub-envs stepped together; 0 = the algorithm's (sac 8, ppo 256,
    #                    multi-car 64)
    failover: bool = True  # a lost server's envs are re-created on a survivor (its episodes end
    #                        truncated); with one server the run ends as without
    max_agents: int = 8  # M, graph nodes per observation (ego + M-1 nearest agents)
    pedestrian_model: str = DEFAULT_MODEL  # model of the simulated crowd (sharedspace.models)
    scenario_pool: str = ""  # scenario file path; "" = scenarios/data/hbs-paper.json
    server_endpoint: str = ""  # Zenoh endpoint of the server; "" = a local sim-server the run
    #                            starts, serving the run's pools and world
    server_params: str = ""  # world-parameter file of that local server; "" = its defaults
    server_prefix: str = "sharedspace"  # Zenoh key prefix of the server
    zenoh_config: str = ""  # trainer session file (deploy/trainer.json5); "" = peer on endpoint
    variations: dict[str, Any] = field(
        default_factory=dict
    )  # scene variations of the training envs (SPEC 5.2.1; JSON on --set); {} = none
    scenes: int = 0  # composed scenes the training envs draw beside the recorded train scenes
    #                  (SPEC 5.2.2, from their recorded parts, never a validation or test
    #                  scene's); 0 = none; -1 = a fresh one every episode, no recorded ones
    scenes_seed: int = 0  # the composed scenes' generator seed (the same scenes for every seed)
    vehicle_model: str = ""  # cars nobody controls: replay | idm (reactive); "" = the pool's
    reward: str = ""  # named reward (sharedspace.train.reward): world | learner; "" = the
    #                   algorithm's (sac world; ppo and multi-car learner)
    reward_weights: dict[str, float] = field(
        default_factory=dict
    )  # weights over the named reward's (SPEC 8.2 names; JSON on --set); {} = none
    base_driver: str = "auto"  # scripted driver the policy's action adds to (residual); "" =
    #                            none; auto = the algorithm's ("" one car, car_aware several)
    residual_scale: float = 0.0  # env action = clip(script + residual_scale * policy's); 0 =
    #                              the algorithm's (1 one car, 2 several); needs base_driver
    # --- on-policy: PPO, MAPPO, IPPO (docs/ARCHITECTURE.md "Learners" says why these values)
    rollout_steps: int = 32  # T, steps of every sub-env per iteration: batch = num_envs * T
    ppo_epochs: int = 0  # passes over each batch; 0 = the algorithm's (ppo 2, mappo/ippo 4)
    minibatch_size: int = 0  # frames per gradient step; 0 = the algorithm's (ppo 2048, 512)
    clip_epsilon: float = 0.2  # PPO's ratio clip
    entropy_coeff: float = 0.0  # entropy bonus weight (the TanhNormal's entropy is estimated)
    critic_coeff: float = 0.5  # the value loss's weight in the summed loss (ppo)
    lmbda: float = 0.95  # GAE lambda
    max_grad_norm: float = 0.0  # global gradient-norm clip; 0 = the algorithm's (ppo 0.5, 1)
    reward_scale: float = 0.1  # rewards are multiplied by this before GAE (ppo: targets ~1)
    normalize_obs: bool = True  # running mean/std of the node features (FeatureNorm; ppo)
    update_threads: int = 0  # torch CPU threads while updating (0 = every core)
    overlap: bool = False  # collect the next batch while updating, one update behind (on-policy,
    #                        sharedspace.train.overlap); off: it does not pay on 2 cores
    anneal_lr: bool = False  # lr falls linearly to 0 at total_frames (CleanRL, TorchRL sota PPO)
    anneal_start: float = 0.0  # share of total_frames at which that fall starts (0 = at once)
    # --- off-policy: SAC, MASAC
    frames_per_batch: int = 0  # frames per collector batch; 0 = the algorithm's (sac
    #                            num_envs * 8, masac 2048)
    init_random_frames: int = 5_000  # frames collected by a uniform random policy first (sac)
    utd_ratio: float = 0.0  # gradient updates per collected frame; 0 = the algorithm's (sac
    #                         0.5, masac 0.02)
    batch_size: int = 256  # replay minibatch size
    buffer_size: int = 0  # replay capacity (transitions); 0 = the algorithm's (200 000, 100 000)
    lr: float = 3e-4  # Adam learning rate of actor, critics and temperature
    gamma: float = 0.99  # discount factor
    tau: float = 0.005  # soft target update coefficient (theta' <- tau theta + (1-tau) theta')
    alpha_init: float = 0.0  # initial entropy temperature (learned, target entropy = -|A|); 0 =
    #                          the algorithm's (sac 1, masac 0.01)
    loss_function: str = "l2"  # critic loss: l2 | smooth_l1 (sac)
    critic_layer_norm: bool = False  # LayerNorm after each hidden layer of the critics (RLPD)
    critic_warmup: int = 0  # gradient updates of the critics alone before actor and alpha learn
    actor_warmup_frames: int = 20_000  # masac: frames of critic-only updates first
    actor_lr: float = 3e-5  # masac: the actor's Adam learning rate (critics and alpha use lr)
    residual_penalty: float = 10.0  # masac: + this x mean(pre-tanh residual mean ^ 2), actor loss
    # --- prior data (RLPD, Ball et al. 2023; sharedspace.train.prior, `make demos`)
    prior_data: str = ""  # dataset directory of recorded transitions; "" = online data only
    prior_sources: str = ""  # comma-separated sources of it to use (e.g. car_aware); "" = all
    prior_successes_only: bool = False  # only the transitions of episodes that reached the goal
    prior_ratio: float = 0.5  # share of every replay batch drawn from the prior data
    bc_weight: float = (
        0.0  # TD3+BC term (x mean|Q|) in the actor loss (prior rows; or to base); 0 off
    )
    bc_steps: int = 0  # behaviour-cloning steps of the actor on the prior data before collecting
    # --- networks
    hidden_sizes: list[int] = field(default_factory=list)  # MLP head widths; [] = the
    #                                                        algorithm's ([256, 256]; [128, 128])
    gcn_hidden: int = 64  # width of each GCN layer's output
    gcn_layers: int = 2  # number of GCN layers (ignored by mlp)
    readout: str = "ego_mean"  # graph readout: "ego" (node 0) | "ego_mean" (node 0 ++ mean)
    share_params: bool = True  # several cars: one network for every car (they are alike)
    init_scale: float = 0.4  # several cars: the policy's initial action standard deviation
    # --- evaluation, logging, checkpoints
    eval_interval: int = -1  # frames between scorings (0 = never; -1 = the algorithm's: sac
    #                          20 000, ppo 524 288, multi-car 60 000), and once at the end
    eval_split: str = "validation"  # validation (carved from the train scenes) | test
    validation_scenes: int = 12  # train scenes carved off as the validation split
    validation_variations: int = 8  # seeded variations of each validation scene per scoring
    checkpoint_interval: int = 50_000  # frames between checkpoints (0 = only at the end)
    save_buffer: bool = False  # include the replay buffer in checkpoints
    log_dir: str = "runs/default"  # run directory: metrics.csv, TensorBoard events, checkpoints
    progress: bool = True  # show a tqdm progress bar

    def __post_init__(self):
        try:
            algo = get_algorithm(self.algorithm)
            task_left = algo.multi_car and not self.task
            if task_left:
                self.task = "crossing"  # the one task of several learning cars
            task = training_task(self.task) if self.task else None
        except (UnknownAlgorithm, UnknownTask) as err:
            raise ConfigError(str(err)) from None
        check_algorithm_options(self)
        # Fields left to the algorithm, the task or the machine are filled in; `_auto`
        # remembers which (with the value they were given), so that an override of the
        # algorithm or the task fills them in again.
        auto = {k: v for k, v in AUTO_FIELDS.items() if getattr(self, k) == v}
        if self.device == "auto":
            auto["device"] = "auto"
        if task_left:
            auto["task"] = ""
        if task is not None:
            auto |= self._take_task(task, algo)
        self._auto = auto
        for name in AUTO_FIELDS:
            if name in auto:
                value = algo.defaults.get(name, BASE_DEFAULTS.get(name, AUTO_FIELDS[name]))
                setattr(self, name, copy.deepcopy(value))
        try:
            several = task is not None and task.cars > 1
            if self.network or not several:  # "": the multi-car flat observation
                self.network = canonical_network(self.network)
        except UnknownNetwork as err:
            raise ConfigError(str(err)) from None
        if self.device == "auto":
            import torch

            self.device = "cuda" if torch.cuda.is_available() else "cpu"
        if "residual_scale" not in auto and not self.base_driver:
            raise ConfigError(
                "residual_scale scales a residual over a script: set base_driver (a residual "
                "without a script)"
            )
        self._check_values()

    def _take_task(self, task, algo) -> dict[str, Any]:
        """The task's training world into the fields it sets (a world field given another
        value than the task's is a :class:`ConfigError` naming it; the training variations and
        the validation split's size may be set: neither changes the task's test side); returns
        the fields it filled in, with their defaults."""
        if not algo.drives(task.cars):
            raise ConfigError(
                f"task {task.name} has {task.cars} learning car(s) per scene and algorithm "
                f"{algo.name} learns {'several' if algo.multi_car else 'one'}: one of "
                f"{', '.join(algorithm_names('many' if task.cars > 1 else 'one'))}"
            )
        values = {
            "scenario_pool": task.pool,
            "server_params": task.server_params,
            "max_agents": task.max_agents,
            "variations": dict(task.variations),
            "validation_scenes": task.validation_scenes,
            "validation_variations": task.validation_variations,
        }
        filled = {}
        for name, value in values.items():
            unset, given = declared_default(self, name), getattr(self, name)
            if given == unset or given == value:
                setattr(self, name, value)
                filled[name] = unset
            elif name not in TRAINING_CHOICES:  # the world's
                raise ConfigError(
                    f"{name} is set by task={task.name} ({value!r}); this config gives {given!r}"
                )
        return filled

    def _check_values(self) -> None:
        if self.reward not in REWARDS:
            raise ConfigError(f"reward must be one of {sorted(REWARDS)}, not {self.reward!r}")
        self.env_spec("train", self.seed, self.variations)  # names a wrong env field now
        if self.readout not in ("ego", "ego_mean"):
            raise ConfigError(f"readout must be ego or ego_mean, not {self.readout!r}")
        if self.eval_split not in ("validation", "test"):
            raise ConfigError(f"eval_split must be validation or test, not {self.eval_split!r}")
        from sharedspace.scripted import SCRIPTED  # torch: imported once a config is made

        if self.base_driver and self.base_driver not in SCRIPTED:
            raise ConfigError(f"base_driver must be one of {sorted(SCRIPTED)} or empty")
        if not 0.0 <= self.anneal_start < 1.0:
            raise ConfigError(f"anneal_start must be in [0, 1), not {self.anneal_start}")
        if not 0.0 <= self.prior_ratio < 1.0:
            raise ConfigError(f"prior_ratio must be in [0, 1), not {self.prior_ratio}")
        if self.bc_steps > 0 and not self.prior_data:
            raise ConfigError("bc_steps clone the prior data: set prior_data")
        if self.bc_weight > 0 and not (self.prior_data or self.base_driver):
            raise ConfigError("bc_weight imitates the prior data or the base driver: set one")
        if get_algorithm(self.algorithm).fused_networks_only:
            if not self.network or not get_network(self.network).fused_sac:
                raise ConfigError(
                    f"network {self.network}: algorithm {self.algorithm}'s fused update knows "
                    "the built-in encoders only (gcn_risk, gcn_uniform, mlp)"
                )
        if self.scenes < -1 or self.scenes_seed < 0:
            raise ConfigError(
                f"scenes must be -1 (a fresh one every episode), 0 (none) or a count, not "
                f"{self.scenes}; scenes_seed at least 0, not {self.scenes_seed}"
            )
        names = ("total_frames", "num_envs", "rollout_steps", "ppo_epochs", "minibatch_size")
        names += ("validation_scenes", "validation_variations")
        for name in names:
            if getattr(self, name) < 1:
                raise ConfigError(f"{name} must be at least 1, not {getattr(self, name)}")

    @property
    def world_reward_weights(self) -> dict[str, float]:
        """The weights sent with the envs: the named reward's, then ``reward_weights``."""
        return {**REWARDS[self.reward], **self.reward_weights}

    def network_config(self) -> NetworkConfig:
        """The part of this config a network's encoder is built from."""
        return NetworkConfig(
            network=self.network,
            max_agents=self.max_agents,
            gcn_hidden=self.gcn_hidden,
            gcn_layers=self.gcn_layers,
            readout=self.readout,
            device=self.device,
        )

    def world(self) -> dict[str, Any]:
        """What a checkpoint records of the world it was trained in: the task (if any), pool
        (the validation pool carved from it too), world parameters, M, crowd, cars, variations
        and reward."""
        keys = ("task", "scenario_pool", "server_params", "max_agents", "pedestrian_model")
        out: dict[str, Any] = {k: getattr(self, k) for k in keys}
        out |= {"vehicle_model": self.vehicle_model, "variations": dict(self.variations)}
        if self.scenes:
            out["composed"] = {"scenes": self.scenes, "seed": self.scenes_seed}
        out["reward"] = {"name": self.reward, "weights": self.world_reward_weights}
        if self.eval_split == "validation":
            out["validation"] = {"scenes": self.validation_scenes, "seed": 0}
        return out

    def validation_names(self) -> tuple[str, ...]:
        """The train scenes of ``scenario_pool`` carved off as the validation split, in pool
        order (:func:`sharedspace.worlds.validation_pool`: ``random.Random(0).sample``); none
        with ``eval_split=test``. The training envs never draw them (``CreateEnv.exclude``), so
        any server of the pool serves every trainer's carve. Reads the pool file once per
        process and writes nothing."""
        if self.eval_split != "validation":
            return ()
        return held_out_scenes(self.scenario_pool, self.validation_scenes)[1]

    def pool_scenes(self) -> list[dict[str, Any]]:
        """``scenario_pool``'s scenes in pool order: what an env's ``scenario_index`` indexes."""
        return load_pool(self.scenario_pool or None)

    def scene_indices(self, split: str) -> list[int]:
        """Indices into :meth:`pool_scenes` of the recorded scenes an env of ``split`` plays:
        the train scenes less the validation split (``train``), the validation split, or the
        test scenes."""
        pool = self.pool_scenes()
        if split == "test":
            return split_indices(pool, "test")
        held = set(self.validation_names())
        keep = split == "validation"
        return [i for i in split_indices(pool, "train") if (pool[i]["name"] in held) == keep]

    def env_spec(self, split: str, seed: int, variations: dict[str, Any] | None = None) -> EnvSpec:
        """The envs this config trains or evaluates on: ``split`` (``train`` draws the pool's
        train scenes less the validation split; ``validation`` envs play the validation scenes
        by name, :func:`sharedspace.train.envs.make_env`), ``seed`` and scene ``variations``.
        Writes nothing."""
        return EnvSpec(
            # the default by its name (hbs-paper, never "the server's first pool"); a file by
            # its path, which the envs read
            pool=self.scenario_pool or held_out_scenes("", 0)[0],
            split="test" if split == "test" else "train",
            seed=seed,
            pedestrian_model=self.pedestrian_model,
            max_agents=self.max_agents,
            variations=variations or None,
            vehicle_model=self.vehicle_model or None,
            reward_weights=self.world_reward_weights,
            exclude=self.validation_names() if split == "train" else (),
            composed=self.composed_scenes() if split == "train" else None,
        )

    def composed_scenes(self) -> ComposedScenes | None:
        """The training envs' composed scenes (``scenes``): made from the train scenes of
        ``scenario_pool`` less the validation split (its test scenes never enter either);
        None for ``scenes=0``. Reads the pool file (the scenes' names) and writes nothing."""
        if self.scenes == 0:
            return None
        held = self.validation_scenes if self.eval_split == "validation" else 0
        source, hold_out = held_out_scenes(self.scenario_pool, held)
        return ComposedScenes(
            scenes=None if self.scenes < 0 else self.scenes,
            seed=self.scenes_seed,
            source=source,
            hold_out=hold_out,
        )

    def connection(self) -> Connection:
        """Where the envs live (:meth:`sharedspace.client.Connection.resolve`): the zenoh file,
        else the endpoint, else a local ``sim-server`` of this config's pool (the server's
        embedded pools for the default) and parameters; with ``failover``."""
        pools = [self.scenario_pool]
        params = self.server_params or None
        if params and self.task and params == training_task(self.task).server_params:
            params = str(world_params_file(training_task(self.task)))  # found outside a checkout
        conn = Connection.resolve(
            self.server_endpoint,
            self.server_prefix,
            self.zenoh_config,
            [p for p in pools if p],
            params,
        )
        return conn.replace(failover=self.failover) if self.failover else conn

    RETIRED_FIELDS = RETIRED_FIELDS
    RENAMED_FIELDS = RENAMED_FIELDS

    @classmethod
    def from_dict(cls, fields: dict[str, Any]) -> TrainConfig:
        """A config from a saved one (a checkpoint's, ``config.json``, a multi-car run's own
        config of before the one config): renamed fields under their names, retired ones and
        the options of other algorithms dropped (older configs held every option), and values
        equal to the algorithm's defaults left to it again."""
        return cls(**cls.saved_fields(fields))

    @classmethod
    def saved_fields(cls, fields: dict[str, Any], algorithm: str | None = None) -> dict[str, Any]:
        """The fields of a saved config as :meth:`from_dict` takes them (for ``algorithm``, if
        given, rather than the saved one's), without building the config."""
        fields = {RENAMED_FIELDS.get(k, k): v for k, v in fields.items() if k not in RETIRED_FIELDS}
        if algorithm:
            fields["algorithm"] = algorithm
        fields.pop("eval_envs", None)  # configs before the validation split
        if "hidden" in fields or "depth" in fields:  # the multi-car config's MLP
            hidden, depth = fields.pop("hidden", 128), fields.pop("depth", 2)
            fields["hidden_sizes"] = [int(hidden)] * int(depth)
        try:
            algo = get_algorithm(fields.get("algorithm", cls.algorithm))
        except UnknownAlgorithm as err:
            raise ConfigError(str(err)) from None
        old_batch = "rollout_steps" not in fields and fields.get("frames_per_batch")
        if algo.family == "on" and algo.multi_car and old_batch:  # the multi-car config's
            num_envs = int(fields.get("num_envs") or algo.defaults.get("num_envs", 64))
            fields["rollout_steps"] = int(fields["frames_per_batch"]) // num_envs
        known = {f.name for f in dataclasses.fields(cls)}
        others = {n for a in ALGORITHMS.values() for n in a.options if n not in algo.options}
        out = {k: v for k, v in fields.items() if k in known and k not in others}
        for name, unset in AUTO_FIELDS.items():
            default = algo.defaults.get(name, BASE_DEFAULTS.get(name, unset))
            if name in out and out[name] == default:
                out[name] = copy.deepcopy(unset)
        return out

    def to_dict(self) -> dict[str, Any]:
        return dataclasses.asdict(self)

    def unresolved(self) -> dict[str, Any]:
        """:meth:`to_dict` with the fields this config filled in by itself (``num_envs``,
        ``reward``, ``device``, ``eval_interval``, a task's fields) as they were given: what
        overrides apply over."""
        return self.to_dict() | getattr(self, "_auto", {})


def declared_default(cfg, name: str) -> Any:
    """The default a config dataclass (or an instance of it) declares for its field ``name``
    (a fresh copy)."""
    f = cfg.__dataclass_fields__[name]
    return f.default_factory() if f.default_factory is not dataclasses.MISSING else f.default


def check_algorithm_options(cfg) -> None:
    """An option that only other algorithms than ``cfg.algorithm`` read (their registered
    ``options``), set away from its default, is a
    :class:`ConfigError` naming it: it would silently do nothing."""
    fields = {f.name for f in dataclasses.fields(cfg)}
    mine = get_algorithm(cfg.algorithm)
    for algo in ALGORITHMS.values():
        for name in algo.options:
            if name in mine.options or name not in fields:
                continue
            if getattr(cfg, name) != declared_default(cfg, name):
                owners = [a.name for a in ALGORITHMS.values() if name in a.options]
                raise ConfigError(
                    f"{name} is an option of algorithm={'|'.join(owners)}, and this config's "
                    f"algorithm is {cfg.algorithm}"
                )


def parse_value(key: str, text: str, like: Any) -> Any:
    """``text`` parsed as the type of ``like`` (the field's current value): booleans as
    true/false/1/0/yes/no/on/off, integers (``1e4`` too), floats, lists as ``256,256`` or
    ``[256, 256]``, dicts as JSON objects; anything else is the string. A value that does not
    parse is a :class:`ConfigError` naming ``key``."""
    try:
        if isinstance(like, bool):
            if text.lower() in ("1", "true", "yes", "on"):
                return True
            if text.lower() in ("0", "false", "no", "off"):
                return False
            raise ValueError("not a boolean")
        if isinstance(like, int):
            return int(float(text)) if "e" in text.lower() else int(text)
        if isinstance(like, float):
            return float(text)
        if isinstance(like, list):
            return [int(x) for x in text.strip("[]").split(",") if x.strip()]
        if isinstance(like, dict):
            value = json.loads(text) if text.strip() else {}
            if not isinstance(value, dict):
                raise ValueError("not a JSON object")
            return value
    except ValueError as exc:
        raise ConfigError(f"--set {key}={text}: expected {type(like).__name__} ({exc})") from None
    return text


def apply_overrides(cfg, overrides: list[str] | dict[str, Any]):
    """A copy of the config dataclass ``cfg`` (:class:`TrainConfig`) with ``key=value``
    strings (or a dict) applied; string values are parsed by the field's type
    (:func:`parse_value`), as the command line's :func:`load_config` parses them."""
    data = cfg.unresolved()
    items = (
        overrides.items() if isinstance(overrides, dict) else (o.split("=", 1) for o in overrides)
    )
    for item in items:
        if len(item) != 2:
            raise ConfigError(f"--set {item[0]!r}: expected KEY=VALUE")
        key, value = _field_name(item[0].strip()), item[1]
        if key is None:  # a retired field
            continue
        data[key] = parse_value(key, value, data[key]) if isinstance(value, str) else value
    return type(cfg)(**data)  # strict: an option of another algorithm is named, not dropped


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
        like = given.get(key, (saved or {}).get(key, declared_default(TrainConfig, key)))
        given[key] = parse_value(key, text, like)
    algorithm = given.get("algorithm") or (
        None if saved is not None else default_algorithm or TrainConfig.algorithm
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
    """``key`` as a field of :class:`TrainConfig`: a renamed field under its new name, None for
    a retired one; an unknown key is an :class:`UnknownFieldError`."""
    key = RENAMED_FIELDS.get(key, key)
    if key in RETIRED_FIELDS:
        return None
    known = TrainConfig.__dataclass_fields__
    if key not in known:
        raise UnknownFieldError(
            f"unknown config key {key!r}{did_you_mean(key, known)}; "
            "`python -m sharedspace.train --help` lists every key"
        )
    return key


def _read_table(path: str | Path) -> dict[str, Any]:
    p = Path(path)
    return tomllib.loads(p.read_text()) if p.suffix == ".toml" else json.loads(p.read_text())
