"""TorchRL's own SAC loss over the trainer's networks: the reference the trainer's learner
(:mod:`sharedspace.train.update`) is tested against."""

from __future__ import annotations

from torch import optim
from torchrl.objectives import SoftUpdate
from torchrl.objectives.sac import SACLoss

from sharedspace.train.config import TrainConfig


def make_loss(cfg: TrainConfig, actor, critic) -> tuple[SACLoss, SoftUpdate]:
    """SAC loss (two critics, learned temperature, target entropy -|A|) and soft target update."""
    loss = SACLoss(
        actor_network=actor,
        qvalue_network=critic,
        num_qvalue_nets=2,
        loss_function=cfg.algo.loss_function,
        alpha_init=cfg.algo.alpha_init,
        delay_actor=False,
        delay_qvalue=True,
    )
    loss.make_value_estimator(gamma=cfg.algo.gamma)
    return loss, SoftUpdate(loss, tau=cfg.algo.tau)


def make_optimizers(cfg: TrainConfig, loss: SACLoss) -> dict[str, optim.Optimizer]:
    """Adam for the actor, the critics and ``log_alpha``."""
    return {
        "actor": optim.Adam(
            list(loss.actor_network_params.flatten_keys().values()), lr=cfg.algo.lr
        ),
        "critic": optim.Adam(
            list(loss.qvalue_network_params.flatten_keys().values()), lr=cfg.algo.lr
        ),
        "alpha": optim.Adam([loss.log_alpha], lr=cfg.algo.lr),
    }
