"""SAC(-GCN), the paper's learner (Algorithm 2): the ``make_*`` builders, TorchRL style (actor,
critics, learner, buffer, collector; the env is :func:`sharedspace.train.envs.make_env`), and
the loop :func:`train`, top to bottom.

The loop writes into ``log_dir``: ``config.json``, ``metrics.csv`` (long format: frames, wall_s,
metric, value; metrics namespaced ``train/`` and ``eval/``), TensorBoard events, and
``checkpoints/{step_<frames>,last}.pt`` (:mod:`sharedspace.train.checkpoint`).
"""

from __future__ import annotations

import time
from pathlib import Path
from typing import Any

import numpy as np
import torch
import tqdm
from torchrl.collectors import Collector
from torchrl.data import LazyTensorStorage, TensorDictReplayBuffer
from torchrl.envs import EnvBase
from torchrl.modules import ProbabilisticActor, ValueOperator

from sharedspace.train.checkpoint import load_checkpoint, save_checkpoint
from sharedspace.train.config import TrainConfig
from sharedspace.train.envs import make_env
from sharedspace.train.evaluation import evaluate_split
from sharedspace.train.gcn import QNet
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
from sharedspace.train.prior import clone, make_prior, mixed_batch
from sharedspace.train.run import next_multiple, seed_everything, start_run
from sharedspace.train.update import SACUpdate

__all__ = [
    "OBS_KEYS",
    "make_actor",
    "make_critic",
    "make_update",
    "make_replay_buffer",
    "make_collector",
    "train",
]


def make_actor(cfg: TrainConfig, action_spec) -> ProbabilisticActor:
    """Graph encoder + MLP -> TanhNormal over the normalised action box ``[-1, 1]^2``; a
    residual actor starts at its script with :data:`RESIDUAL_INIT_SCALE`."""
    init = RESIDUAL_INIT_SCALE if cfg.base_driver else None
    return make_gaussian_actor(cfg, action_spec, make_encoder(cfg), init_scale=init)


def make_critic(cfg: TrainConfig, action_spec) -> ValueOperator:
    """``Q(s, a)``: its own graph encoder + MLP; SACLoss makes the two critics and targets."""
    net = QNet(
        make_encoder(cfg), cfg.hidden_sizes, action_spec.shape[-1], layer_norm=cfg.critic_layer_norm
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
        gamma=cfg.gamma,
        tau=cfg.tau,
        lr=cfg.lr,
        alpha_init=cfg.alpha_init,
        loss_function=cfg.loss_function,
        action_dim=action_spec.shape[-1],
        bc_weight=cfg.bc_weight,
        residual=bool(cfg.base_driver),
    ).to(cfg.device)


def make_replay_buffer(cfg: TrainConfig) -> TensorDictReplayBuffer:
    """Uniform replay over a preallocated (lazy) tensor storage of ``buffer_size`` transitions;
    its batches are the online part of a replay batch (all of it without prior data)."""
    prior_rows = round(cfg.batch_size * cfg.prior_ratio) if cfg.prior_data else 0
    return TensorDictReplayBuffer(
        storage=LazyTensorStorage(cfg.buffer_size, device=cfg.device),
        batch_size=cfg.batch_size - prior_rows,
    )


def batch_frames(cfg: TrainConfig) -> int:
    """Frames per collected batch: ``frames_per_batch``, or 0: ``num_envs * 8``."""
    return cfg.frames_per_batch or cfg.num_envs * 8


def make_collector(
    cfg: TrainConfig, env: EnvBase, actor, total_frames: int, init_random_frames: int
) -> Collector:
    """``Collector`` over the batched env: batches ``[K, frames_per_batch / K]``; done sub-envs
    are reset through ``step_and_maybe_reset`` (partial ``_reset``)."""
    return Collector(
        env,
        actor,
        frames_per_batch=batch_frames(cfg),
        total_frames=total_frames,
        init_random_frames=init_random_frames,
        device=cfg.device,
        env_device="cpu",
        auto_register_policy_transforms=False,  # the policy is not recurrent
    )


def train(cfg: TrainConfig, resume: str | None = None) -> dict[str, Any]:
    """Runs SAC on ``cfg`` (paper Algorithm 2); returns the final counters and the last
    evaluation summary."""
    log_dir = start_run(cfg)

    # ---- counters, possibly from a checkpoint
    ckpt = load_checkpoint(resume, cfg.device) if resume else None
    counters = {"frames": 0, "updates": 0, "episodes": 0, "iterations": 0, "clone_steps": 0}
    counters["lost_episodes"] = 0
    if ckpt is not None:
        counters.update(ckpt["counters"])
    prior = make_prior(cfg)  # RLPD's prior data (refused here if of another world)
    seed_everything(cfg.seed + counters["frames"])

    # ---- env, networks, loss, optimisers, buffer
    env = make_env(
        cfg, split="train", seed=cfg.seed + counters["frames"], variations=cfg.variations
    )
    actor = make_actor(cfg, env.action_spec_unbatched)
    with torch.no_grad():
        actor(env.fake_tensordict().to(cfg.device))
    update = make_update(cfg, actor, env.action_spec_unbatched)
    buffer = make_replay_buffer(cfg)
    if ckpt is not None:
        if "learner" not in ckpt:
            raise ValueError(
                f"{resume} was written by the TorchRL SACLoss learner (before 2026-12-03); it "
                "can be evaluated but not resumed"
            )
        update.load_state_dict(ckpt["learner"])
        update.load_optimizer_state(ckpt["optimizers"])
        if ckpt.get("buffer_dir") and Path(ckpt["buffer_dir"]).exists():
            buffer.loads(ckpt["buffer_dir"])
        if "torch_rng" in ckpt:
            torch.set_rng_state(ckpt["torch_rng"])

    # ---- the actor cloned on the prior data first, if asked
    logger = MetricLogger(log_dir)
    if prior is not None and counters["clone_steps"] < cfg.bc_steps:
        losses = clone(update, prior, cfg.bc_steps - counters["clone_steps"], cfg)
        counters["clone_steps"] = cfg.bc_steps
        logger.log({"train/loss_clone": float(np.mean(losses[-100:]))}, counters["frames"])
        _checkpoint(log_dir, cfg, actor, update, counters, buffer)

    # ---- collector over the remaining frames
    remaining = max(cfg.total_frames - counters["frames"], 0)
    init_random = max(cfg.init_random_frames - counters["frames"], 0)
    tracker = EpisodeTracker(env.batch_size[0])
    last_eval: dict[str, float] = {}
    if remaining == 0:
        env.close()
        logger.close()
        return {"counters": counters, "eval": last_eval}
    collector = make_collector(cfg, env, actor, remaining, init_random)
    num_updates = max(1, int(batch_frames(cfg) * cfg.utd_ratio))
    next_eval = next_multiple(counters["frames"], cfg.eval_interval)
    next_ckpt = next_multiple(counters["frames"], cfg.checkpoint_interval)

    pbar = tqdm.tqdm(
        total=cfg.total_frames,
        initial=counters["frames"],
        disable=not cfg.progress,
        unit="fr",
        dynamic_ncols=True,
    )
    wall0 = time.perf_counter()
    env_t0 = env.env_time_s
    t_iter = time.perf_counter()
    env_t_iter = env.env_time_s
    for data in collector:
        # ---- store
        frames = data.numel()
        counters["frames"] += frames
        counters["iterations"] += 1
        ended = tracker.update(data)
        counters["episodes"] += len(ended)
        counters["lost_episodes"] += int(sum(e["lost"] for e in ended))
        buffer.extend(data.exclude("loc", "scale").reshape(-1))

        # ---- learn (after the random warm-up)
        losses: dict[str, list[float]] = {}
        if counters["frames"] >= cfg.init_random_frames and len(buffer) >= cfg.batch_size:
            for _ in range(num_updates):
                batch, prior_rows = mixed_batch(buffer, prior, cfg)
                warm = counters["updates"] >= cfg.critic_warmup
                out = update.step(batch.to(cfg.device), prior_rows, train_actor=warm)
                counters["updates"] += 1
                for key, value in out.items():
                    losses.setdefault(key, []).append(float(value.detach()))
        collector.update_policy_weights_()

        # ---- log
        now = time.perf_counter()
        env_now = env.env_time_s
        metrics = {
            "train/fps": frames / max(now - t_iter, 1e-9),
            "train/env_time_share": (env_now - env_t_iter) / max(now - t_iter, 1e-9),
            "train/env_time_share_cum": (env_now - env_t0) / max(now - wall0, 1e-9),
            "train/updates": counters["updates"],
            "train/buffer": len(buffer),
            "train/reward_mean": float(data["next", "reward"].mean()),
        }
        t_iter, env_t_iter = now, env_now
        for key, vals in losses.items():
            metrics[f"train/{key}"] = float(np.mean(vals))
        metrics.update(episode_metrics(ended))
        metrics["train/episodes"] = counters["episodes"]
        logger.log(metrics, counters["frames"])
        pbar.update(frames)
        pbar.set_postfix(progress_postfix(metrics, tracker.recent))

        # ---- evaluate, checkpoint
        if cfg.eval_interval and counters["frames"] >= next_eval:
            next_eval = next_multiple(counters["frames"], cfg.eval_interval)
            last_eval = evaluate_split(cfg, actor, cfg.eval_split)["summary"]
            logger.log({f"eval/{k}": v for k, v in last_eval.items()}, counters["frames"])
        if cfg.checkpoint_interval and counters["frames"] >= next_ckpt:
            next_ckpt = next_multiple(counters["frames"], cfg.checkpoint_interval)
            _checkpoint(log_dir, cfg, actor, update, counters, buffer)

    pbar.close()
    collector.shutdown()
    _checkpoint(log_dir, cfg, actor, update, counters, buffer)
    logger.close()
    return {
        "counters": counters,
        "eval": last_eval,
        "env_time_share": (env.env_time_s - env_t0) / max(time.perf_counter() - wall0, 1e-9),
    }


def _checkpoint(log_dir, cfg, actor, update, counters, buffer) -> None:
    d = log_dir / "checkpoints"
    save_checkpoint(d / f"step_{counters['frames']}.pt", cfg, actor, update, counters)
    # The replay buffer goes with last.pt only: it is what a resumed run continues from.
    save_checkpoint(
        d / "last.pt", cfg, actor, update, counters, buffer if cfg.save_buffer else None
    )
