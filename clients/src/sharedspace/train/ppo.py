"""PPO on wide batches of envs: the ``make_*`` builders, TorchRL style, and the learner the
training loop (:mod:`sharedspace.train.loop`) drives.

    python -m sharedspace.train --set algorithm=ppo network=gcn_risk task=paper

Each iteration steps ``num_envs`` (K) sub-envs ``rollout_steps`` (T) times, one ``BatchStep``
per step for all K, with the current policy; computes advantages by GAE (TorchRL's ``GAE``,
bootstrapping on truncation, not on termination); then runs ``ppo_epochs`` passes of TorchRL's
``ClipPPOLoss`` over minibatches of ``minibatch_size`` frames, advantages normalised per
minibatch. The actor (tanh-normal) and the value critic each have their own encoder of the
config's network (GCN over the risk graph, over the uniform graph, or the MLP), with one
running normalisation of the node features shared by both (:class:`~sharedspace.train.gcn.
FeatureNorm`, updated after each iteration's update). With ``base_driver`` the policy is a
residual over that script (:class:`~sharedspace.train.envs.ResidualAction`), starting at it.

Why these defaults (docs/ARCHITECTURE.md, "Learners"): K = 256 and T = 32 give 8 192 fresh
frames per iteration; 2 epochs of minibatches of 2 048 (8 gradient steps) reach a driver sooner
in wall time than 4 did, the update being most of a 2-core iteration (docs/BENCHMARKS.md, "The
time to a driver"); rewards are scaled by
0.1 so that value targets are of order 1.

"""

from __future__ import annotations

from typing import Any

import torch
from tensordict import TensorDictBase
from torch import nn
from torchrl.envs import EnvBase
from torchrl.modules import ProbabilisticActor, ValueOperator
from torchrl.objectives import ClipPPOLoss
from torchrl.objectives.value import GAE

from sharedspace.train.config import TrainConfig
from sharedspace.train.gcn import FeatureNorm, mlp
from sharedspace.train.loop import OneCar, torch_threads
from sharedspace.train.policy import (
    OBS_KEYS,
    RESIDUAL_INIT_SCALE,
    make_encoder,
    make_gaussian_actor,
)

__all__ = [
    "PPOLearner",
    "PPOUpdate",
    "make_actor",
    "make_critic",
    "make_learner",
    "make_update",
    "make_world",
]

#: The spread of a from-scratch actor's Gaussian (before the tanh) at initialisation.
SCRATCH_INIT_SCALE = 1.0


def make_actor(
    cfg: TrainConfig, action_spec, norm: FeatureNorm | None = None
) -> ProbabilisticActor:
    """The tanh-normal policy over the config's network; the collected data carry each
    action's log-probability. It starts at ``loc`` 0: the script, for a residual policy (with
    :data:`~sharedspace.train.policy.RESIDUAL_INIT_SCALE`), else holding speed and heading on
    average with a wide spread. ``norm``: the feature normalisation it shares with the critic
    (a new one with ``normalize_obs``, none without)."""
    if norm is None and cfg.algo.normalize_obs:
        norm = FeatureNorm()
    init = RESIDUAL_INIT_SCALE if cfg.algo.base_driver else SCRATCH_INIT_SCALE
    return make_gaussian_actor(
        action_spec,
        make_encoder(cfg.net, norm),
        cfg.algo.hidden_sizes,
        cfg.device,
        init_scale=init,
        return_log_prob=True,
    )


def encoder_of(actor: ProbabilisticActor) -> nn.Module:
    """The encoder inside an actor of :func:`make_actor`."""
    return actor.module[0].module.net.encoder


def feature_norm_of(actor: ProbabilisticActor) -> FeatureNorm | None:
    """The feature normalisation inside a PPO actor (None without, or where the network
    holds none)."""
    return getattr(encoder_of(actor), "norm", None)


class ValueNet(nn.Module):
    """Encoder + MLP to the state value ``V(s) [*, 1]``."""

    def __init__(self, encoder, hidden_sizes):
        super().__init__()
        self.encoder = encoder
        self.head = mlp([encoder.out_features, *hidden_sizes], out=1)

    def forward(self, features, adjacency, mask):
        return self.head(self.encoder(features, adjacency, mask))


def make_critic(cfg: TrainConfig, norm: FeatureNorm | None) -> ValueOperator:
    """``V(s)``: its own encoder of the config's network (sharing ``norm`` with the actor)."""
    net = ValueNet(make_encoder(cfg.net, norm), cfg.algo.hidden_sizes)
    return ValueOperator(net, in_keys=OBS_KEYS, out_keys=["state_value"]).to(cfg.device)


def annealed_lr(cfg: TrainConfig, frames: int) -> float:
    """The learning rate ``frames`` into a run with ``anneal_lr``: ``lr`` until
    ``anneal_start * total_frames``, then falling linearly to 0 at ``total_frames``. A late
    start keeps the early learning of a constant rate and still lets the policy settle, so that
    the run's last checkpoint is its policy."""
    left = 1.0 - frames / cfg.total_frames
    return cfg.algo.lr * min(max(left / max(1.0 - cfg.algo.anneal_start, 1e-9), 0.0), 1.0)


class PPOUpdate(nn.Module):
    """One iteration's learning on a collected batch ``[K, T]``: GAE, then ``ppo_epochs``
    passes of ``ClipPPOLoss`` over shuffled minibatches, then the feature normalisation folds
    the batch in. ``state_dict`` / ``optimizer_state`` are what a checkpoint keeps."""

    def __init__(self, cfg: TrainConfig, actor: ProbabilisticActor, critic: ValueOperator):
        super().__init__()
        self.cfg = cfg
        self.actor, self.critic = actor, critic
        self.loss = ClipPPOLoss(
            actor_network=actor,
            critic_network=critic,
            clip_epsilon=cfg.algo.clip_epsilon,
            entropy_bonus=cfg.algo.entropy_coeff > 0,
            entropy_coeff=cfg.algo.entropy_coeff if cfg.algo.entropy_coeff > 0 else None,
            critic_coeff=cfg.algo.critic_coeff,
            loss_critic_type="l2",
            normalize_advantage=True,
        )
        self.gae = GAE(
            gamma=cfg.algo.gamma,
            lmbda=cfg.algo.lmbda,
            value_network=critic,
            average_gae=False,
            deactivate_vmap=True,  # the encoders trim padding nodes: a data-dependent shape
        )
        self.optimizer = torch.optim.Adam(self.loss.parameters(), lr=cfg.algo.lr)
        # The minibatches' shuffles draw from their own generator: with the overlap, the
        # collector thread samples actions from torch's global one meanwhile, and a shared
        # generator would make a run's draws depend on the threads' timing.
        self.shuffle = torch.Generator(device=cfg.device).manual_seed(torch.initial_seed())
        self.log_prob_key = self.loss.tensor_keys.sample_log_prob

    def step(self, data: TensorDictBase, frames: int = 0) -> dict[str, float]:
        """Learns from ``data`` (rewards as the env gave them), ``frames`` into the run (with
        ``anneal_lr`` the learning rate falls linearly from ``lr`` at ``anneal_start`` of the
        run to 0 at its end: :func:`annealed_lr`); returns the means of the losses and of the
        clip fraction, KL estimate and explained variance."""
        cfg = self.cfg
        if cfg.algo.anneal_lr:
            for group in self.optimizer.param_groups:
                group["lr"] = annealed_lr(cfg, frames)
        data = data.to(cfg.device)
        data["next", "reward"] = data["next", "reward"] * cfg.algo.reward_scale
        with torch.no_grad():
            self.gae(data)
        keys = [*OBS_KEYS, "action", self.log_prob_key, "advantage", "value_target"]
        flat = data.select(*keys, "state_value").reshape(-1)
        n = flat.numel()
        mb = min(cfg.algo.minibatch_size, n)
        sums: dict[str, float] = {}
        steps = 0
        for _ in range(cfg.algo.ppo_epochs):
            perm = torch.randperm(n, device=flat.device, generator=self.shuffle)
            for start in range(0, n - mb + 1, mb):
                batch = flat[perm[start : start + mb]]
                out = self.loss(batch)
                total = out["loss_objective"] + out["loss_critic"]
                if "loss_entropy" in out.keys():
                    total = total + out["loss_entropy"]
                self.optimizer.zero_grad(set_to_none=True)
                total.backward()
                grad_norm = nn.utils.clip_grad_norm_(self.loss.parameters(), cfg.algo.max_grad_norm)
                self.optimizer.step()
                steps += 1
                for key in (
                    "loss_objective",
                    "loss_critic",
                    "loss_entropy",
                    "clip_fraction",
                    "kl_approx",
                ):
                    if key in out.keys():
                        sums[key] = sums.get(key, 0.0) + float(out[key].detach())
                sums["grad_norm"] = sums.get("grad_norm", 0.0) + float(grad_norm)
        update_norm = getattr(encoder_of(self.actor), "update_norm", None)
        if update_norm is not None:  # a registered network may hold no normalisation
            update_norm(flat["features"], flat["mask"])
        stats = {k: v / max(steps, 1) for k, v in sums.items()}
        value, target = flat["state_value"], flat["value_target"]
        stats["explained_variance"] = float(
            1 - (target - value).var() / target.var().clamp_min(1e-8)
        )
        stats["gradient_steps"] = steps
        stats["lr"] = self.optimizer.param_groups[0]["lr"]
        return stats

    def optimizer_state(self) -> dict[str, Any]:
        return {"adam": self.optimizer.state_dict()}

    def load_optimizer_state(self, state: dict[str, Any]) -> None:
        self.optimizer.load_state_dict(state["adam"])


def make_update(cfg: TrainConfig, actor: ProbabilisticActor) -> PPOUpdate:
    """The learner over ``actor`` and a new value critic sharing its feature normalisation."""
    return PPOUpdate(cfg, actor, make_critic(cfg, feature_norm_of(actor))).to(cfg.device)


class PPOLearner:
    """PPO as the training loop (:mod:`sharedspace.train.loop`) drives it: the actor, and one
    iteration's update per collected batch ``[K, T]`` (the server waits meanwhile, so every
    core may serve the update: ``update_threads``)."""

    def __init__(self, cfg: TrainConfig, action_spec):
        self.cfg = cfg
        self.actor = make_actor(cfg, action_spec)
        self.update = make_update(cfg, self.actor)
        self.batch_frames = cfg.algo.num_envs * cfg.algo.rollout_steps
        self.random_frames = 0

    def start(self, counters: dict[str, Any], logger) -> None:
        """Nothing before the first batch."""

    def step(self, data: TensorDictBase, counters: dict[str, Any]) -> dict[str, float]:
        torch_threads(self.cfg.algo.update_threads)
        stats = self.update.step(data, counters["frames"] - data.numel())
        torch_threads(self.cfg.num_threads)
        counters["updates"] += int(stats.pop("gradient_steps"))
        stats["action_scale"] = float(data["scale"].mean())  # the spread, before the tanh
        return stats

    def state_dict(self) -> dict[str, Any]:
        return self.update.state_dict()

    def optimizer_state(self) -> dict[str, Any]:
        return self.update.optimizer_state()

    def load(self, ckpt: dict[str, Any]) -> None:
        self.actor.load_state_dict(ckpt["actor"])
        self.update.load_state_dict(ckpt["learner"])
        self.update.load_optimizer_state(ckpt["optimizers"])
        torch.set_rng_state(ckpt["torch_rng"])


#: PPO plays one car per env (:class:`~sharedspace.train.loop.OneCar`).
make_world = OneCar


def make_learner(cfg: TrainConfig, world: OneCar, env: EnvBase) -> PPOLearner:
    """The learner of the training loop."""
    return PPOLearner(cfg, env.action_spec_unbatched)
