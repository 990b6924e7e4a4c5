"""One configuration of a multi-car run, with a line of doc per field."""

from __future__ import annotations

import dataclasses
import json
from dataclasses import dataclass
from typing import Any

__all__ = ["ALGORITHMS", "LEARNER_REWARD", "MarlConfig", "apply_overrides"]

#: MAPPO (shared centralised critic), IPPO (each car's own critic input), MASAC (centralised
#: Q-critics, off-policy).
ALGORITHMS = ("mappo", "ippo", "masac")

#: The learners' reward weights over the world's defaults (SPEC 8.2 names). Under the world's
#: (danger 20, collision -20) the car-aware script's car-episodes return +1 on success, -107 on
#: a collision and -343 on a timeout (the danger term of a car standing by a pedestrian, every
#: step until the horizon), so running into the pedestrian pays better than waiting: MASAC's
#: critics found that within one batch. Here a success returns +24, a timeout -32, a collision
#: -109 (`python bench/marl_script_returns.py`: the script on 64 training scenes of seed 5).
LEARNER_REWARD: dict[str, float] = {"danger": 2.0, "collision": -100.0}


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
    reward_weights: dict[str, float] = dataclasses.field(
        default_factory=lambda: dict(LEARNER_REWARD)
    )  # overrides of the world's reward weights (SPEC 8.2 names; JSON on --set); {} = the world's
    eval_every: int = 60_000  # frames between evaluations on the test scenes (curves only)
    # --- policy
    base_driver: str = "car_aware"  # the policy's action is a residual over this script; "" off
    residual_scale: float = 2.0  # the env's action = clip(script + residual_scale * policy's)
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
        if self.algorithm not in ALGORITHMS:
            raise ValueError(f"algorithm must be one of {ALGORITHMS}, got {self.algorithm!r}")
        for name in ("total_frames", "num_envs", "frames_per_batch", "minibatch_size"):
            if getattr(self, name) < 1:
                raise ValueError(f"{name} must be at least 1, got {getattr(self, name)}")

    def to_dict(self) -> dict[str, Any]:
        return dataclasses.asdict(self)


def apply_overrides(cfg: MarlConfig, sets: list[str]) -> MarlConfig:
    """``key=value`` overrides (values parsed as JSON, else taken as strings), checked by name
    and type."""
    fields = {f.name: f for f in dataclasses.fields(MarlConfig)}
    values = cfg.to_dict()
    for item in sets:
        key, sep, raw = item.partition("=")
        if not sep or key not in fields:
            raise ValueError(f"--set {item!r}: expected key=value with key one of {sorted(fields)}")
        try:
            value = json.loads(raw)
        except json.JSONDecodeError:
            value = raw
        want = type(values[key])
        if want is float and isinstance(value, int) and not isinstance(value, bool):
            value = float(value)
        if not isinstance(value, want) or (want is int and isinstance(value, bool)):
            raise ValueError(f"--set {key}: expected {want.__name__}, got {raw!r}")
        values[key] = value
    return MarlConfig(**values)
