"""MASAC (TorchRL's ``sota-implementations/multiagent/sac.py``): two centralised Q-critics
``Q(s, a)`` per car over every car's observation and action, target critics, learned
temperature; TorchRL's ``SACLoss`` with TD(0), ``utd_ratio`` updates per collected frame from a
replay buffer.

Two choices keep a residual policy near its script while the critics are untrained: the actor
waits ``actor_warmup_frames`` (critics only), then learns at its own, smaller rate
(``actor_lr``), and pays ``residual_penalty`` x its mean's square. Adam moves each weight by
about the rate per step whatever the gradient's size: at the critics' rate 40 steps shift the
residual's mean by about 1 (measured: the residual turned the script's 0.70 success into 0.03
within one batch)."""

from __future__ import annotations

import torch
from tensordict import TensorDictBase
from tensordict.nn import TensorDictSequential
from torch import nn
from torchrl.data import LazyTensorStorage, TensorDictReplayBuffer
from torchrl.data.replay_buffers.samplers import RandomSampler
from torchrl.modules import ValueOperator
from torchrl.objectives import SACLoss, SoftUpdate, ValueEstimators

from sharedspace.marl.networks import ACTION, GROUP, OBS, agents_mlp, observation
from sharedspace.marl.task import CrossingTask
from sharedspace.marl.train import Cars, learner_of
from sharedspace.train.config import TrainConfig

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
    """``Q(s, a)`` per car over every car's observation and action."""
    mlp = agents_mlp(cfg, task, extra_inputs=2, outputs=1, centralized=True)
    value = ValueOperator(
        module=mlp, in_keys=[OBS, ACTION], out_keys=[(GROUP, "state_action_value")]
    )
    return TensorDictSequential(observation(cfg, task), value)


def make_loss(cfg: TrainConfig, actor, critic) -> SACLoss:
    """TorchRL's ``SACLoss`` (two Q-critics, delayed targets) with TD(0) on the group's keys."""
    loss = SACLoss(
        actor_network=actor,
        qvalue_network=critic,
        num_qvalue_nets=2,
        delay_qvalue=True,
        alpha_init=cfg.algo.alpha_init,
        target_entropy=-2.0,  # per car: -|A|
    )
    loss.set_keys(
        reward=(GROUP, "reward"),
        action=ACTION,
        done=(GROUP, "done"),
        terminated=(GROUP, "terminated"),
        state_action_value=(GROUP, "state_action_value"),
    )
    loss.make_value_estimator(ValueEstimators.TD0, gamma=cfg.algo.gamma)
    return loss


def make_optimizer(cfg: TrainConfig, loss: nn.Module) -> torch.optim.Optimizer:
    """Adam; the actor at ``actor_lr``, the critics and the temperature at ``lr``."""
    actor = list(loss.actor_network_params.values(True, True))
    others = [p for p in loss.parameters() if all(p is not a for a in actor)]
    return torch.optim.Adam(
        [{"params": actor, "lr": cfg.algo.actor_lr}, {"params": others}], cfg.algo.lr
    )


def make_buffer(cfg: TrainConfig, frames_per_batch: int) -> TensorDictReplayBuffer:
    """A replay buffer of ``buffer_size`` sub-env steps, sampled at random."""
    return TensorDictReplayBuffer(
        storage=LazyTensorStorage(cfg.algo.buffer_size),
        sampler=RandomSampler(),
        batch_size=cfg.algo.batch_size,
    )


def make_target_update(cfg: TrainConfig, loss: nn.Module) -> SoftUpdate:
    return SoftUpdate(loss, eps=1.0 - cfg.algo.tau)


def learn(
    cfg: TrainConfig, loss, optim, buffer, data: TensorDictBase, target_update, frames: int
) -> dict[str, float]:
    """One collected batch into the buffer, then ``utd_ratio`` updates per frame; only the
    critics learn for the first ``actor_warmup_frames``. Returns the last step's losses and the
    steps taken."""
    warmup = frames < cfg.algo.actor_warmup_frames
    buffer.extend(data.reshape(-1))
    steps = max(1, round(cfg.algo.utd_ratio * data.numel()))
    for _ in range(steps):
        sample = buffer.sample()
        out = loss(sample)
        if cfg.algo.residual_penalty and not warmup:
            # keeps the residual near 0 (the script) unless the critics disagree by more
            loc = loss.actor_network(sample.clone())[GROUP, "loc"]
            out["loss_residual"] = cfg.algo.residual_penalty * loc.pow(2).mean()
        losses = [v for k, v in out.items() if k.startswith("loss_")]
        total = out["loss_qvalue"] if warmup else sum(losses)
        optim.zero_grad()
        total.backward()
        nn.utils.clip_grad_norm_(loss.parameters(), cfg.algo.max_grad_norm)
        optim.step()
        if target_update is not None:
            target_update.step()
    losses = {k: float(v.detach().mean()) for k, v in out.items() if k.startswith("loss_")}
    return losses | {"gradient_steps": steps}


#: The training loop's world and learner: the crossing task's cars, this module's update.
make_world, make_learner = Cars, learner_of(__name__)
