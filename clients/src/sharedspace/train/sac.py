"""SAC(-GCN), the paper's learner (Algorithm 2): the ``make_*`` builders, TorchRL style (actor,
critics, update, buffer; the env is :func:`sharedspace.train.envs.make_env`), and the learner
the training loop (:mod:`sharedspace.train.loop`) drives.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
import torch
from tensordict import TensorDictBase
from torchrl.data import LazyTensorStorage, TensorDictReplayBuffer
from torchrl.envs import EnvBase
from torchrl.modules import ProbabilisticActor, ValueOperator

from sharedspace.train.config import TrainConfig
from sharedspace.train.gcn import QNet
from sharedspace.train.loop import OneCar
from sharedspace.train.policy import (
    OBS_KEYS,
    RESIDUAL_INIT_SCALE,
    make_encoder,
    make_gaussian_actor,
)
from sharedspace.train.prior import clone, make_prior, mixed_batch
from sharedspace.train.update import SACUpdate

__all__ = [
    "OBS_KEYS",
    "SACLearner",
    "make_actor",
    "make_critic",
    "make_learner",
    "make_replay_buffer",
    "make_update",
    "make_world",
]


def make_actor(cfg: TrainConfig, action_spec) -> ProbabilisticActor:
    """Graph encoder + MLP -> TanhNormal over the normalised action box ``[-1, 1]^2``; a
    residual actor starts at its script with :data:`RESIDUAL_INIT_SCALE`."""
    init = RESIDUAL_INIT_SCALE if cfg.algo.base_driver else None
    encoder = make_encoder(cfg.net)
    return make_gaussian_actor(
        action_spec, encoder, cfg.algo.hidden_sizes, cfg.device, init_scale=init
    )


def make_critic(cfg: TrainConfig, action_spec) -> ValueOperator:
    """``Q(s, a)``: its own graph encoder + MLP; SACLoss makes the two critics and targets."""
    net = QNet(
        make_encoder(cfg.net),
        cfg.algo.hidden_sizes,
        action_spec.shape[-1],
        layer_norm=cfg.algo.critic_layer_norm,
    )
    return ValueOperator(net, in_keys=[*OBS_KEYS, "action"]).to(cfg.device)


def make_update(cfg: TrainConfig, actor, action_spec, num_critics: int = 2) -> SACUpdate:
    """The learner: SAC's losses, target critics, optimisers and gradient step
    (:mod:`sharedspace.train.update`), training ``actor`` in place. Its critics are initialised
    like ``num_critics`` separate :func:`make_critic` networks."""
    qnets = [make_critic(cfg, action_spec).module for _ in range(num_critics)]
    return SACUpdate(
        actor,
        qnets,
        gamma=cfg.algo.gamma,
        tau=cfg.algo.tau,
        lr=cfg.algo.lr,
        alpha_init=cfg.algo.alpha_init,
        loss_function=cfg.algo.loss_function,
        action_dim=action_spec.shape[-1],
        bc_weight=cfg.algo.bc_weight,
        residual=bool(cfg.algo.base_driver),
    ).to(cfg.device)


def make_replay_buffer(cfg: TrainConfig) -> TensorDictReplayBuffer:
    """Uniform replay over a preallocated (lazy) tensor storage of ``buffer_size`` transitions;
    its batches are the online part of a replay batch (all of it without prior data)."""
    prior_rows = round(cfg.algo.batch_size * cfg.algo.prior_ratio) if cfg.algo.prior_data else 0
    return TensorDictReplayBuffer(
        storage=LazyTensorStorage(cfg.algo.buffer_size, device=cfg.device),
        batch_size=cfg.algo.batch_size - prior_rows,
    )


def batch_frames(cfg: TrainConfig) -> int:
    """Frames per collected batch: ``frames_per_batch``, or 0: ``num_envs * 8``."""
    return cfg.algo.frames_per_batch or cfg.algo.num_envs * 8


class SACLearner:
    """SAC as the training loop (:mod:`sharedspace.train.loop`) drives it: the actor, the
    replay buffer (and the prior data mixed into its batches), and ``utd_ratio`` updates per
    collected frame once the random warm-up is over."""

    def __init__(self, cfg: TrainConfig, env: EnvBase):
        self.cfg = cfg
        self.prior = make_prior(cfg)  # RLPD's prior data (refused here if of another world)
        spec = env.action_spec_unbatched
        self.actor = make_actor(cfg, spec)
        with torch.no_grad():
            self.actor(env.fake_tensordict().to(cfg.device))
        self.update = make_update(cfg, self.actor, spec)
        self.buffer = make_replay_buffer(cfg)
        self.batch_frames = batch_frames(cfg)
        self.random_frames = cfg.algo.init_random_frames
        self.num_updates = max(1, int(self.batch_frames * cfg.algo.utd_ratio))

    def start(self, counters: dict[str, Any], logger) -> None:
        """The actor cloned on the prior data first, if asked (``bc_steps``)."""
        done = counters.setdefault("clone_steps", 0)
        if self.prior is not None and done < self.cfg.algo.bc_steps:
            losses = clone(self.update, self.prior, self.cfg.algo.bc_steps - done, self.cfg)
            counters["clone_steps"] = self.cfg.algo.bc_steps
            logger.log({"train/loss_clone": float(np.mean(losses[-100:]))}, counters["frames"])

    def step(self, data: TensorDictBase, counters: dict[str, Any]) -> dict[str, float]:
        cfg = self.cfg
        self.buffer.extend(data.exclude("loc", "scale").reshape(-1))
        losses: dict[str, list[float]] = {}
        if (
            counters["frames"] >= cfg.algo.init_random_frames
            and len(self.buffer) >= cfg.algo.batch_size
        ):
            for _ in range(self.num_updates):
                batch, prior_rows = mixed_batch(self.buffer, self.prior, cfg)
                warm = counters["updates"] >= cfg.algo.critic_warmup
                out = self.update.step(batch.to(cfg.device), prior_rows, train_actor=warm)
                counters["updates"] += 1
                for key, value in out.items():
                    losses.setdefault(key, []).append(float(value.detach()))
        stats = {key: float(np.mean(vals)) for key, vals in losses.items()}
        return stats | {"buffer": len(self.buffer)}

    def state_dict(self) -> dict[str, Any]:
        return self.update.state_dict()

    def optimizer_state(self) -> dict[str, Any]:
        return self.update.optimizer_state()

    def load(self, ckpt: dict[str, Any]) -> None:
        if "learner" not in ckpt:
            raise ValueError(
                "this checkpoint was written by the TorchRL SACLoss learner (before "
                "2026-12-03); it can be evaluated but not resumed"
            )
        self.actor.load_state_dict(ckpt["actor"])
        self.update.load_state_dict(ckpt["learner"])
        self.update.load_optimizer_state(ckpt["optimizers"])
        if ckpt.get("buffer_dir") and Path(ckpt["buffer_dir"]).exists():
            self.buffer.loads(ckpt["buffer_dir"])
        if "torch_rng" in ckpt:
            torch.set_rng_state(ckpt["torch_rng"])


#: SAC plays one car per env (:class:`~sharedspace.train.loop.OneCar`).
make_world = OneCar


def make_learner(cfg: TrainConfig, world: OneCar, env: EnvBase) -> SACLearner:
    """The learner of the training loop."""
    return SACLearner(cfg, env)
