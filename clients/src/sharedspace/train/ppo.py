"""PPO on wide batches of envs: the ``make_*`` builders, TorchRL style, and the loop
:func:`train`, top to bottom.

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
frames per iteration, enough that 4 epochs of minibatches of 2 048 (16 gradient steps) neither
starve the update nor spend most of the wall time in it on a 2-core CPU; rewards are scaled by
0.1 so that value targets are of order 1.

Writes into ``log_dir`` what the SAC loop writes: ``config.json``, ``metrics.csv``, TensorBoard
events and ``checkpoints/{step_<frames>,last}.pt``.
"""

from __future__ import annotations

import contextlib
import os
import time
from typing import Any

import torch
import tqdm
from tensordict import TensorDictBase
from torch import nn
from torchrl.collectors import Collector
from torchrl.envs import EnvBase
from torchrl.modules import ProbabilisticActor, ValueOperator
from torchrl.objectives import ClipPPOLoss
from torchrl.objectives.value import GAE

from sharedspace.train.checkpoint import load_checkpoint, save_checkpoint
from sharedspace.train.config import TrainConfig
from sharedspace.train.envs import make_env
from sharedspace.train.evaluation import evaluate_split
from sharedspace.train.gcn import FeatureNorm, mlp
from sharedspace.train.metrics import (
    EpisodeTracker,
    MetricLogger,
    episode_metrics,
    progress_postfix,
)
from sharedspace.train.policy import (
    OBS_KEYS,
    RESIDUAL_INIT_SCALE,
    make_encoder,
    make_gaussian_actor,
)
from sharedspace.train.run import next_multiple, seed_everything, start_run

__all__ = [
    "PPOUpdate",
    "make_actor",
    "make_collector",
    "make_critic",
    "make_update",
    "train",
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
    if norm is None and cfg.normalize_obs:
        norm = FeatureNorm()
    init = RESIDUAL_INIT_SCALE if cfg.base_driver else SCRATCH_INIT_SCALE
    return make_gaussian_actor(
        cfg, action_spec, make_encoder(cfg, norm), init_scale=init, return_log_prob=True
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
    net = ValueNet(make_encoder(cfg, norm), cfg.hidden_sizes)
    return ValueOperator(net, in_keys=OBS_KEYS, out_keys=["state_value"]).to(cfg.device)


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
            clip_epsilon=cfg.clip_epsilon,
            entropy_bonus=cfg.entropy_coeff > 0,
            entropy_coeff=cfg.entropy_coeff if cfg.entropy_coeff > 0 else None,
            critic_coeff=cfg.critic_coeff,
            loss_critic_type="l2",
            normalize_advantage=True,
        )
        self.gae = GAE(
            gamma=cfg.gamma,
            lmbda=cfg.lmbda,
            value_network=critic,
            average_gae=False,
            deactivate_vmap=True,  # the encoders trim padding nodes: a data-dependent shape
        )
        self.optimizer = torch.optim.Adam(self.loss.parameters(), lr=cfg.lr)
        self.log_prob_key = self.loss.tensor_keys.sample_log_prob

    def step(self, data: TensorDictBase, frames: int = 0) -> dict[str, float]:
        """Learns from ``data`` (rewards as the env gave them), ``frames`` into the run (with
        ``anneal_lr`` the learning rate is ``lr * (1 - frames / total_frames)``); returns the
        means of the losses and of the clip fraction, KL estimate and explained variance."""
        cfg = self.cfg
        if cfg.anneal_lr:
            for group in self.optimizer.param_groups:
                group["lr"] = cfg.lr * max(1.0 - frames / cfg.total_frames, 0.0)
        data = data.to(cfg.device)
        data["next", "reward"] = data["next", "reward"] * cfg.reward_scale
        with torch.no_grad():
            self.gae(data)
        keys = [*OBS_KEYS, "action", self.log_prob_key, "advantage", "value_target"]
        flat = data.select(*keys, "state_value").reshape(-1)
        n = flat.numel()
        mb = min(cfg.minibatch_size, n)
        sums: dict[str, float] = {}
        steps = 0
        for _ in range(cfg.ppo_epochs):
            perm = torch.randperm(n, device=flat.device)
            for start in range(0, n - mb + 1, mb):
                batch = flat[perm[start : start + mb]]
                out = self.loss(batch)
                total = out["loss_objective"] + out["loss_critic"]
                if "loss_entropy" in out.keys():
                    total = total + out["loss_entropy"]
                self.optimizer.zero_grad(set_to_none=True)
                total.backward()
                grad_norm = nn.utils.clip_grad_norm_(self.loss.parameters(), cfg.max_grad_norm)
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


def batch_frames(cfg: TrainConfig) -> int:
    """Frames per iteration: ``num_envs * rollout_steps``."""
    return cfg.num_envs * cfg.rollout_steps


def make_collector(cfg: TrainConfig, env: EnvBase, actor, total_frames: int) -> Collector:
    """``Collector`` over the batched env: batches ``[K, T]`` of the current policy; done
    sub-envs are reset by the server's autoreset (``step_and_maybe_reset``)."""
    return Collector(
        env,
        actor,
        frames_per_batch=batch_frames(cfg),
        total_frames=total_frames,
        device=cfg.device,
        env_device="cpu",
        auto_register_policy_transforms=False,  # the policy is not recurrent
    )


def train(cfg: TrainConfig, resume: str | None = None) -> dict[str, Any]:
    """Runs PPO on ``cfg``; returns the final counters, the last evaluation's summary and
    where the time went (``timing``: collection, of it the env's round trips, updates,
    evaluations; seconds)."""
    log_dir = start_run(cfg)

    # ---- counters, env, networks and learner, possibly from a checkpoint
    ckpt = load_checkpoint(resume, cfg.device) if resume else None
    counters = {"frames": 0, "updates": 0, "episodes": 0, "iterations": 0, "lost_episodes": 0}
    counters |= ckpt["counters"] if ckpt is not None else {}
    seed_everything(cfg.seed + counters["frames"])
    env = make_env(
        cfg, split="train", seed=cfg.seed + counters["frames"], variations=cfg.variations
    )
    actor = make_actor(cfg, env.action_spec_unbatched)
    update = make_update(cfg, actor)
    if ckpt is not None:
        _restore(ckpt, actor, update)
    remaining = max(cfg.total_frames - counters["frames"], 0)
    logger = MetricLogger(log_dir)
    clock = Clock(env)
    last_eval: dict[str, float] = {}
    if remaining == 0:
        env.close()
        logger.close()
        return {"counters": counters, "eval": last_eval, "timing": clock.timing}
    collector = make_collector(cfg, env, actor, remaining)
    tracker = EpisodeTracker(cfg.num_envs)
    next_eval = next_multiple(counters["frames"], cfg.eval_interval)
    next_ckpt = next_multiple(counters["frames"], cfg.checkpoint_interval)
    pbar = tqdm.tqdm(
        total=cfg.total_frames,
        initial=counters["frames"],
        disable=not cfg.progress,
        unit="fr",
        dynamic_ncols=True,
    )
    for data in collector:
        clock.collected()  # ---- collected: the outcomes of the episodes that ended
        counters["frames"] += data.numel()
        counters["iterations"] += 1
        ended = tracker.update(data)
        counters["episodes"] += len(ended)
        counters["lost_episodes"] += int(sum(e["lost"] for e in ended))
        reward_mean = float(data["next", "reward"].mean())
        action_scale = float(data["scale"].mean())  # the policy's spread (before the tanh)

        # ---- learn (the server waits meanwhile: every core may serve the update)
        torch.set_num_threads(cfg.update_threads or os.cpu_count() or 1)
        stats = update.step(data, counters["frames"] - data.numel())
        torch.set_num_threads(cfg.num_threads or os.cpu_count() or 1)
        counters["updates"] += int(stats.pop("gradient_steps"))
        collector.update_policy_weights_()
        clock.updated()

        # ---- log
        metrics = clock.metrics(data.numel()) | {f"train/{k}": v for k, v in stats.items()}
        metrics |= {"train/reward_mean": reward_mean, "train/action_scale": action_scale}
        metrics["train/episodes"] = counters["episodes"]
        metrics |= episode_metrics(ended)
        logger.log(metrics, counters["frames"])
        pbar.update(data.numel())
        pbar.set_postfix(progress_postfix(metrics, tracker.recent))

        # ---- evaluate (curves only: nothing is chosen on them), checkpoint
        if cfg.eval_interval and counters["frames"] >= next_eval:
            next_eval = next_multiple(counters["frames"], cfg.eval_interval)
            last_eval = _evaluate(cfg, actor, clock, logger, counters["frames"])
        if cfg.checkpoint_interval and counters["frames"] >= next_ckpt:
            next_ckpt = next_multiple(counters["frames"], cfg.checkpoint_interval)
            _checkpoint(log_dir, cfg, actor, update, counters)
        clock.collecting()

    pbar.close()
    collector.shutdown()
    _checkpoint(log_dir, cfg, actor, update, counters)
    if cfg.eval_interval and last_eval.get("frames") != counters["frames"]:  # the run's policy
        last_eval = _evaluate(cfg, actor, clock, logger, counters["frames"])
    logger.close()
    return {"counters": counters, "eval": last_eval, "timing": clock.timing}


def _evaluate(cfg, actor, clock: Clock, logger: MetricLogger, frames: int) -> dict[str, float]:
    """Every scene of ``eval_split`` once, deterministic; logged as ``eval/*`` with the
    training wall time so far. A curve: nothing is chosen on it."""
    with clock.evaluating():
        summary = evaluate_split(cfg, actor, cfg.eval_split)["summary"] | {"frames": frames}
    row = {f"eval/{k}": v for k, v in summary.items() if k != "frames"}
    logger.log(row | {"eval/train_wall_s": clock.train_s}, frames)
    return summary


def _restore(ckpt: dict[str, Any], actor, update: PPOUpdate) -> None:
    actor.load_state_dict(ckpt["actor"])
    update.load_state_dict(ckpt["learner"])
    update.load_optimizer_state(ckpt["optimizers"])
    torch.set_rng_state(ckpt["torch_rng"])


class Clock:
    """Where a run's wall time goes: collection (of it, the env's round trips), updates and
    evaluations, in seconds (``timing``), and each iteration's ``train/*`` rates."""

    def __init__(self, env):
        self.env = env
        self.env0 = env.env_time_s
        self.timing = {"collect_s": 0.0, "env_s": 0.0, "update_s": 0.0, "eval_s": 0.0}
        self.t_collect = self.t_update = time.perf_counter()

    @property
    def train_s(self) -> float:
        """Collection plus updates: the run's wall time without its evaluations."""
        return self.timing["collect_s"] + self.timing["update_s"]

    def collecting(self) -> None:
        self.t_collect = time.perf_counter()

    def collected(self) -> None:
        self.t_update = time.perf_counter()
        self.timing["collect_s"] += self.t_update - self.t_collect
        self.timing["env_s"] = self.env.env_time_s - self.env0

    def updated(self) -> None:
        self.t_done = time.perf_counter()
        self.timing["update_s"] += self.t_done - self.t_update

    def metrics(self, frames: int) -> dict[str, float]:
        collect_s, update_s = self.t_update - self.t_collect, self.t_done - self.t_update
        return {
            "train/fps": frames / max(collect_s + update_s, 1e-9),
            "train/collect_s": collect_s,
            "train/update_s": update_s,
            "train/env_time_share_cum": self.timing["env_s"] / max(self.train_s, 1e-9),
            "train/wall_s": self.train_s,
        }

    @contextlib.contextmanager
    def evaluating(self):
        t0 = time.perf_counter()
        yield
        self.timing["eval_s"] += time.perf_counter() - t0


def _checkpoint(log_dir, cfg, actor, update, counters) -> None:
    d = log_dir / "checkpoints"
    save_checkpoint(d / f"step_{counters['frames']}.pt", cfg, actor, update, counters)
    save_checkpoint(d / "last.pt", cfg, actor, update, counters)
