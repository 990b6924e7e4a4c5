"""MAPPO and IPPO (TorchRL's ``sota-implementations/multiagent/mappo_ippo.py``): a state-value
critic per car, over every car's observation (MAPPO, centralised) or its own (IPPO); TorchRL's
``ClipPPOLoss`` with GAE; ``ppo_epochs`` passes of minibatches over each collected batch.

Every multi-car algorithm's module has the same functions: ``make_critic``, ``make_loss``,
``make_optimizer``, ``make_buffer``, ``make_target_update`` and ``learn``, which
:class:`~sharedspace.marl.train.CarsLearner` calls from the one training loop
(:mod:`sharedspace.train.loop`), and ``make_world`` / ``make_learner`` for the loop."""

from __future__ import annotations

import torch
from tensordict import TensorDictBase
from tensordict.nn import TensorDictSequential
from torch import nn
from torchrl.data import LazyTensorStorage, TensorDictReplayBuffer
from torchrl.data.replay_buffers.samplers import SamplerWithoutReplacement
from torchrl.modules import ValueOperator
from torchrl.objectives import ClipPPOLoss, ValueEstimators

from sharedspace.marl.networks import ACTION, GROUP, OBS, agents_mlp, observation
from sharedspace.marl.task import CrossingTask
from sharedspace.marl.train import Cars, learner_of
from sharedspace.train.config import TrainConfig
from sharedspace.train.registry import get_algorithm

__all__ = [
    "learn",
    "make_learner",
    "make_world",
    "make_buffer",
    "make_critic",
    "make_loss",
    "make_optimizer",
    "make_target_update",
]


def make_critic(cfg: TrainConfig, task: CrossingTask) -> TensorDictSequential:
    """The state value per car (centralised for MAPPO)."""
    central = get_algorithm(cfg.algorithm).centralized_critic  # MAPPO's; IPPO's is each car's
    mlp = agents_mlp(cfg, task, extra_inputs=0, outputs=1, centralized=central)
    value = ValueOperator(module=mlp, in_keys=[OBS], out_keys=[(GROUP, "state_value")])
    return TensorDictSequential(observation(cfg, task), value)


def make_loss(cfg: TrainConfig, actor, critic) -> ClipPPOLoss:
    """TorchRL's ``ClipPPOLoss`` with GAE on the group's keys; each car's advantages are
    normalised apart."""
    loss = ClipPPOLoss(
        actor_network=actor,
        critic_network=critic,
        clip_epsilon=cfg.algo.clip_epsilon,
        entropy_coeff=cfg.algo.entropy_coeff,
        normalize_advantage=True,
        normalize_advantage_exclude_dims=(-2,),  # each car's advantages normalised apart
    )
    loss.set_keys(
        reward=(GROUP, "reward"),
        action=ACTION,
        done=(GROUP, "done"),
        terminated=(GROUP, "terminated"),
        value=(GROUP, "state_value"),
    )
    loss.make_value_estimator(ValueEstimators.GAE, gamma=cfg.algo.gamma, lmbda=cfg.algo.lmbda)
    return loss


def make_optimizer(cfg: TrainConfig, loss: nn.Module) -> torch.optim.Optimizer:
    return torch.optim.Adam(loss.parameters(), cfg.algo.lr)


def make_buffer(cfg: TrainConfig, frames_per_batch: int) -> TensorDictReplayBuffer:
    """The last batch, in minibatches without replacement."""
    return TensorDictReplayBuffer(
        storage=LazyTensorStorage(frames_per_batch),
        sampler=SamplerWithoutReplacement(),
        batch_size=cfg.algo.minibatch_size,
    )


def make_target_update(cfg: TrainConfig, loss: nn.Module) -> None:
    """PPO has no target networks."""
    return None


def learn(
    cfg: TrainConfig, loss, optim, buffer, data: TensorDictBase, target_update, frames: int
) -> dict[str, float]:
    """One collected batch: advantages by GAE, then ``ppo_epochs`` passes of minibatches.
    Returns the last step's losses (``loss_*``) and the steps taken (``gradient_steps``)."""
    with torch.no_grad():
        loss.value_estimator(
            data,
            params=loss.critic_network_params,
            target_params=loss.target_critic_network_params,
        )
    buffer.extend(data.reshape(-1))
    steps = cfg.algo.ppo_epochs * max(1, data.numel() // cfg.algo.minibatch_size)
    for _ in range(steps):
        out = loss(buffer.sample())
        total = sum(v for k, v in out.items() if k.startswith("loss_"))
        optim.zero_grad()
        total.backward()
        nn.utils.clip_grad_norm_(loss.parameters(), cfg.algo.max_grad_norm)
        optim.step()
    losses = {k: float(v.detach().mean()) for k, v in out.items() if k.startswith("loss_")}
    return losses | {"gradient_steps": steps}


#: The training loop's world and learner: the crossing task's cars, this module's update.
make_world, make_learner = Cars, learner_of(__name__)
