"""Each algorithm's config: a class per algorithm holding its own options with its own defaults
(BenchMARL's ``AlgorithmConfig``), registered with the algorithm
(:mod:`sharedspace.train.registry`, ``Algorithm.config``). A run's config
(:class:`sharedspace.train.config.TrainConfig`) holds one, beside its world and network parts;
an option of another algorithm is refused by name.

Torch-free, so that ``--help`` and the USAGE reference read every default without importing
an implementation. PPO's defaults: docs/ARCHITECTURE.md, "Learners"; the multi-car learners
are a residual over the car-aware script by default, each car's action at twice the script's
weight.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field
from typing import ClassVar

from sharedspace.cli import UserError
from sharedspace.scripted import SCRIPTED
from sharedspace.train.reward import REWARDS

__all__ = [
    "AlgorithmConfig",
    "AlgorithmConfigError",
    "Driving",
    "MappoConfig",
    "MasacConfig",
    "MultiCarConfig",
    "PpoConfig",
    "SacConfig",
]


@dataclass(frozen=True)
class Driving:
    """How a policy drives its envs beyond the world: the scripted driver its action is a
    residual over (``base_driver``, ``residual_scale``), and the reward weights the envs are
    created with. A trainer's: :attr:`sharedspace.train.config.TrainConfig.driving`; the
    default: the policy's action as it is, under the world's reward."""

    base_driver: str = ""  # scripted driver the action adds to; "" = none
    residual_scale: float = 1.0  # env action = clip(script + residual_scale * policy's)
    reward_weights: dict[str, float] = field(default_factory=dict)  # over the world's


class AlgorithmConfigError(UserError):
    """An algorithm option with a wrong value; the message names it."""


@dataclass
class AlgorithmConfig:
    """What every algorithm's config has: its envs, reward, residual and heads."""

    #: The network a run of this algorithm takes when it names none ("": each car's nodes
    #: flattened into its MLP, several cars).
    default_network: ClassVar[str] = "gcn_risk"

    # --- algorithm
    num_envs: int = 8  # K, sub-envs stepped together
    reward: str = "world"  # named reward (sharedspace.train.reward): world | learner
    reward_weights: dict[str, float] = field(
        default_factory=dict
    )  # weights over the named reward's (SPEC 8.2 names; JSON on --set); {} = none
    base_driver: str = ""  # scripted driver the policy's action adds to (residual); "" = none
    residual_scale: float = 1.0  # env action = clip(script + residual_scale * policy's); needs
    #                              base_driver
    hidden_sizes: list[int] = field(default_factory=lambda: [256, 256])  # MLP head widths
    lr: float = 3e-4  # Adam learning rate
    gamma: float = 0.99  # discount factor
    eval_interval: int = 20_000  # frames between scorings (0 = never), and once at the end

    def __post_init__(self):
        if self.reward not in REWARDS:
            raise AlgorithmConfigError(
                f"reward must be one of {sorted(REWARDS)}, not {self.reward!r}"
            )
        if self.base_driver and self.base_driver not in SCRIPTED:
            raise AlgorithmConfigError(f"base_driver must be one of {sorted(SCRIPTED)} or empty")
        if self.residual_scale != type(self).residual_scale and not self.base_driver:
            raise AlgorithmConfigError(
                "residual_scale scales a residual over a script: set base_driver (a residual "
                "without a script)"
            )
        for name in self.counts():
            if getattr(self, name) < 1:
                raise AlgorithmConfigError(f"{name} must be at least 1, not {getattr(self, name)}")

    def counts(self) -> tuple[str, ...]:
        """The options that count something and must be at least 1."""
        return ("num_envs",)

    @property
    def world_reward_weights(self) -> dict[str, float]:
        """The weights sent with the envs: the named reward's, then ``reward_weights``."""
        return {**REWARDS[self.reward], **self.reward_weights}

    @classmethod
    def options(cls) -> tuple[str, ...]:
        """Its ``--set`` keys, in the order of its source."""
        return tuple(f.name for f in dataclasses.fields(cls))


@dataclass
class SacConfig(AlgorithmConfig):
    """SAC (the paper's SAC-GCN, Algorithm 2), with prior data (RLPD, Ball et al. 2023;
    :mod:`sharedspace.train.prior`, ``make demos``)."""

    # --- off-policy
    frames_per_batch: int = 0  # frames per collector batch; 0 = num_envs * 8
    init_random_frames: int = 5_000  # frames collected by a uniform random policy first
    utd_ratio: float = 0.5  # gradient updates per collected frame
    batch_size: int = 256  # replay minibatch size
    buffer_size: int = 200_000  # replay capacity (transitions)
    tau: float = 0.005  # soft target update coefficient (theta' <- tau theta + (1-tau) theta')
    alpha_init: float = 1.0  # initial entropy temperature (learned, target entropy = -|A|)
    loss_function: str = "l2"  # critic loss: l2 | smooth_l1
    critic_layer_norm: bool = False  # LayerNorm after each hidden layer of the critics (RLPD)
    critic_warmup: int = 0  # gradient updates of the critics alone before actor and alpha learn
    save_buffer: bool = False  # include the replay buffer in checkpoints
    # --- prior data
    prior_data: str = ""  # dataset directory of recorded transitions; "" = online data only
    prior_sources: str = ""  # comma-separated sources of it to use (e.g. car_aware); "" = all
    prior_successes_only: bool = False  # only the transitions of episodes that reached the goal
    prior_ratio: float = 0.5  # share of every replay batch drawn from the prior data
    bc_weight: float = 0.0  # TD3+BC term (x mean|Q|) in the actor loss (prior rows; or to
    #                         base); 0 off
    bc_steps: int = 0  # behaviour-cloning steps of the actor on the prior data before collecting

    def __post_init__(self):
        super().__post_init__()
        if not 0.0 <= self.prior_ratio < 1.0:
            raise AlgorithmConfigError(f"prior_ratio must be in [0, 1), not {self.prior_ratio}")
        if self.bc_steps > 0 and not self.prior_data:
            raise AlgorithmConfigError("bc_steps clone the prior data: set prior_data")
        if self.bc_weight > 0 and not (self.prior_data or self.base_driver):
            raise AlgorithmConfigError(
                "bc_weight imitates the prior data or the base driver: set one"
            )


@dataclass
class PpoConfig(AlgorithmConfig):
    """PPO on wide batches of envs. 2 epochs: the time to a driver (docs/BENCHMARKS.md "The
    time to a driver"), chosen on validation; a validation scoring costs about as much as 40 k
    frames of PPO-GCN, so every 524 288 keeps it under a tenth of a run's wall time."""

    num_envs: int = 256  # K, sub-envs stepped together
    reward: str = "learner"  # named reward (sharedspace.train.reward): world | learner
    eval_interval: int = 524_288  # frames between scorings (0 = never), and once at the end
    # --- on-policy
    rollout_steps: int = 32  # T, steps of every sub-env per iteration: batch = num_envs * T
    ppo_epochs: int = 2  # passes over each batch
    minibatch_size: int = 2048  # frames per gradient step
    clip_epsilon: float = 0.2  # PPO's ratio clip
    entropy_coeff: float = 0.0  # entropy bonus weight (the TanhNormal's entropy is estimated)
    critic_coeff: float = 0.5  # the value loss's weight in the summed loss
    lmbda: float = 0.95  # GAE lambda
    max_grad_norm: float = 0.5  # global gradient-norm clip
    reward_scale: float = 0.1  # rewards are multiplied by this before GAE (targets ~1)
    normalize_obs: bool = True  # running mean/std of the node features (FeatureNorm)
    update_threads: int = 0  # torch CPU threads while updating (0 = every core)
    overlap: bool = False  # collect the next batch while updating, one update behind
    #                        (sharedspace.train.overlap); off: it does not pay on 2 cores
    anneal_lr: bool = False  # lr falls linearly to 0 at total_frames (CleanRL, TorchRL sota PPO)
    anneal_start: float = 0.0  # share of total_frames at which that fall starts (0 = at once)

    def __post_init__(self):
        super().__post_init__()
        if not 0.0 <= self.anneal_start < 1.0:
            raise AlgorithmConfigError(f"anneal_start must be in [0, 1), not {self.anneal_start}")

    def counts(self) -> tuple[str, ...]:
        return ("num_envs", "rollout_steps", "ppo_epochs", "minibatch_size")


@dataclass
class MultiCarConfig(AlgorithmConfig):
    """What the multi-car learners (the crossing task's cars) have in common: a residual over
    the car-aware script at twice its weight, and each car's MLP."""

    default_network: ClassVar[str] = ""

    num_envs: int = 64  # K, sub-envs stepped together
    reward: str = "learner"  # named reward (sharedspace.train.reward): world | learner
    base_driver: str = "car_aware"  # scripted driver the policy's action adds to (residual);
    #                                 "" = none
    residual_scale: float = 2.0  # env action = clip(script + residual_scale * policy's); needs
    #                              base_driver
    hidden_sizes: list[int] = field(default_factory=lambda: [128, 128])  # MLP head widths
    eval_interval: int = 60_000  # frames between scorings (0 = never), and once at the end
    # --- several cars
    share_params: bool = True  # one network for every car (they are alike)
    init_scale: float = 0.4  # the policy's initial action standard deviation


@dataclass
class MappoConfig(MultiCarConfig):
    """MAPPO and IPPO (:mod:`sharedspace.marl.mappo`): PPO per car."""

    # --- on-policy
    rollout_steps: int = 32  # T, steps of every sub-env per iteration: batch = num_envs * T
    ppo_epochs: int = 4  # passes over each batch
    minibatch_size: int = 512  # frames per gradient step
    clip_epsilon: float = 0.2  # PPO's ratio clip
    entropy_coeff: float = 0.0  # entropy bonus weight (the TanhNormal's entropy is estimated)
    lmbda: float = 0.95  # GAE lambda
    max_grad_norm: float = 1.0  # global gradient-norm clip
    overlap: bool = False  # collect the next batch while updating, one update behind

    def counts(self) -> tuple[str, ...]:
        return ("num_envs", "rollout_steps", "ppo_epochs", "minibatch_size")


@dataclass
class MasacConfig(MultiCarConfig):
    """MASAC (:mod:`sharedspace.marl.masac`): SAC per car, centralised Q-critics."""

    # --- off-policy
    frames_per_batch: int = 2048  # frames per collector batch
    utd_ratio: float = 0.02  # gradient updates per collected frame
    batch_size: int = 256  # replay minibatch size
    buffer_size: int = 100_000  # replay capacity (transitions)
    tau: float = 0.005  # soft target update coefficient (theta' <- tau theta + (1-tau) theta')
    alpha_init: float = 0.01  # initial entropy temperature (learned, target entropy = -|A|)
    max_grad_norm: float = 1.0  # global gradient-norm clip
    actor_warmup_frames: int = 20_000  # frames of critic-only updates first
    actor_lr: float = 3e-5  # the actor's Adam learning rate (critics and alpha use lr)
    residual_penalty: float = 10.0  # + this x mean(pre-tanh residual mean ^ 2) in the actor loss
