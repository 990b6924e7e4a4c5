"""One configuration of a multi-car run, with a line of doc per field."""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from typing import Any

from sharedspace.client import Connection
from sharedspace.scripted import SCRIPTED
from sharedspace.train.config import ConfigError, apply_overrides, check_algorithm_options
from sharedspace.train.networks import UnknownNetwork, canonical_network
from sharedspace.train.registry import ALGORITHMS as REGISTERED
from sharedspace.train.registry import UnknownAlgorithm, algorithm_names, get_algorithm
from sharedspace.train.reward import REWARDS

__all__ = ["ALGORITHMS", "MarlConfig", "apply_overrides"]

#: MAPPO (shared centralised critic), IPPO (each car's own critic input), MASAC (centralised
#: Q-critics, off-policy): the registered multi-car algorithms
#: (:mod:`sharedspace.train.registry`, their options there).
ALGORITHMS = algorithm_names(cars="many")


@dataclass
class MarlConfig:
    """Every knob of a multi-car run (``python -m sharedspace.marl --set key=value``)."""

    # --- run
    algorithm: str = "mappo"  # mappo | ippo | masac
    seed: int = 0  # seed of torch and of the server's draw of training scenes
    total_frames: int = 300_000  # sub-env steps to collect (each moves every car once)
    num_envs: int = 64  # K, sub-envs stepped together
    num_threads: int = 1  # torch CPU threads
    log_dir: str = "runs/marl"  # config.json, metrics.csv, checkpoint.pt, eval.json go here
    server_endpoint: str = ""  # Zenoh endpoint of the server; "" = start a local sim-server
    server_prefix: str = "sharedspace"  # key prefix of that server
    zenoh_config: str = ""  # trainer session file (deploy/trainer.json5); "" = peer on endpoint
    reward: str = "learner"  # named reward (sharedspace.train.reward): learner | world
    reward_weights: dict[str, float] = dataclasses.field(
        default_factory=dict
    )  # weights over the named reward's (SPEC 8.2 names; JSON on --set); {} = none
    eval_every: int = 60_000  # frames between evaluations on the test scenes (curves only)
    # --- policy
    base_driver: str = "car_aware"  # the policy's action is a residual over this script; "" off
    residual_scale: float = 2.0  # the env's action = clip(script + residual_scale * policy's)
    network: str = ""  # a registered network encoding each car's observation (gcn_risk, ...);
    #                    "" = its node features and mask flattened (the shipped policies')
    gcn_hidden: int = 64  # width of each GCN layer of a registered GCN network
    gcn_layers: int = 2  # GCN layers of a registered GCN network
    readout: str = "ego_mean"  # a registered GCN's readout: ego | ego_mean
    hidden: int = 128  # width of each hidden layer (actor and critic)
    depth: int = 2  # hidden layers
    share_params: bool = True  # one network for every car (the cars are interchangeable)
    init_scale: float = 0.4  # the policy's initial action standard deviation (tanh-normal)
    # --- PPO (mappo, ippo)
    frames_per_batch: int = 2048  # frames per collected batch (PPO: per iteration)
    ppo_epochs: int = 4  # passes over each batch
    minibatch_size: int = 512  # samples (sub-env steps, all cars) per gradient step
    clip_epsilon: float = 0.2  # PPO's ratio clip
    entropy_coeff: float = 0.0  # entropy bonus
    gamma: float = 0.99  # discount
    lmbda: float = 0.95  # GAE lambda
    lr: float = 3e-4  # Adam learning rate
    max_grad_norm: float = 1.0  # gradient clip
    # --- SAC (masac)
    utd_ratio: float = 0.02  # gradient updates per collected frame
    batch_size: int = 256  # replay minibatch (sub-env steps, all cars)
    buffer_size: int = 100_000  # replay capacity (sub-env steps)
    tau: float = 0.005  # target soft-update coefficient
    alpha_init: float = 0.01  # initial entropy temperature (learned)
    actor_warmup_frames: int = 20_000  # frames of critic-only updates before the actor moves
    actor_lr: float = 3e-5  # the actor's Adam learning rate (the critics and alpha use lr)
    residual_penalty: float = 10.0  # + this x mean(pre-tanh residual mean ^ 2) in the actor's loss

    def __post_init__(self) -> None:
        try:
            get_algorithm(self.algorithm, cars="many")
        except UnknownAlgorithm as err:
            raise ConfigError(str(err)) from None
        check_algorithm_options(self)
        if self.network:
            try:
                self.network = canonical_network(self.network)
            except UnknownNetwork as err:
                raise ConfigError(str(err)) from None
        for name in ("total_frames", "num_envs", "frames_per_batch", "minibatch_size"):
            if getattr(self, name) < 1:
                raise ConfigError(f"{name} must be at least 1, got {getattr(self, name)}")
        if self.reward not in REWARDS:
            raise ConfigError(f"reward must be one of {sorted(REWARDS)}, not {self.reward!r}")
        if self.base_driver and self.base_driver not in SCRIPTED:
            raise ConfigError(f"base_driver must be one of {sorted(SCRIPTED)} or empty")
        if not self.base_driver and self.residual_scale != 2.0:
            raise ConfigError(
                "residual_scale scales a residual over a script: set base_driver (a residual "
                "without a script)"
            )

    @property
    def world_reward_weights(self) -> dict[str, float]:
        """The weights sent with the envs: the named reward's, then ``reward_weights``."""
        return {**REWARDS[self.reward], **self.reward_weights}

    def connection(self) -> Connection:
        """Where the envs live: the zenoh file, else the endpoint ("": a local ``sim-server``
        the run starts; :meth:`sharedspace.client.Connection.resolve`)."""
        return Connection.resolve(self.server_endpoint, self.server_prefix, self.zenoh_config)

    @classmethod
    def from_dict(cls, fields: dict[str, Any]) -> MarlConfig:
        return cls(**fields)

    @classmethod
    def from_saved(cls, fields: dict[str, Any]) -> MarlConfig:
        """A run's saved config (a checkpoint's, a ``config.json``). Runs saved before each
        algorithm's options were checked hold every option: those of other algorithms than
        theirs fall back to their defaults, and fields configs no longer have are dropped."""
        known = {f.name for f in dataclasses.fields(cls)}
        algorithm = fields.get("algorithm", cls.algorithm)
        mine = get_algorithm(algorithm).options
        others = {n for a in REGISTERED.values() for n in a.options if n not in mine}
        return cls(**{k: v for k, v in fields.items() if k in known and k not in others})

    def to_dict(self) -> dict[str, Any]:
        return dataclasses.asdict(self)
