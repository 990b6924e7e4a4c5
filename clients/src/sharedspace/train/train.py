"""SAC(-GCN) training, top to bottom (paper Algorithm 2).

    python -m sharedspace.train --config cfg.toml [--set key=value ...] [--resume CKPT]

Writes into ``log_dir``: ``config.json``, ``metrics.csv`` (long format: frames, wall_s, metric,
value; metrics namespaced ``train/`` and ``eval/``), TensorBoard events, and
``checkpoints/{step_<frames>,last}.pt``.
"""

from __future__ import annotations

import csv
import json
import sys
import time
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np
import torch
import tqdm
from tensordict import TensorDictBase

from sharedspace.torchrl_env import EPISODE_FLAG_KEYS, EPISODE_FLOAT_KEYS
from sharedspace.train.config import (
    TrainConfig,
    _read_table,
    add_overrides_argument,
    apply_overrides,
    command_parser,
    load_config,
)
from sharedspace.train.evaluation import evaluate_split
from sharedspace.train.prior import clone, make_prior, mixed_batch
from sharedspace.train.sac import (
    make_actor,
    make_collector,
    make_env,
    make_replay_buffer,
    make_update,
    seed_everything,
)

__all__ = ["MetricLogger", "train", "main"]


class MetricLogger:
    """Scalars to ``metrics.csv`` (long format) and TensorBoard."""

    def __init__(self, log_dir: Path, tensorboard: bool = True):
        log_dir.mkdir(parents=True, exist_ok=True)
        path = log_dir / "metrics.csv"
        new = not path.exists()
        self._file = path.open("a", newline="")
        self._csv = csv.writer(self._file)
        if new:
            self._csv.writerow(["frames", "wall_s", "metric", "value"])
        self._tb = None
        if tensorboard:
            try:
                from torch.utils.tensorboard import SummaryWriter

                self._tb = SummaryWriter(str(log_dir / "tb"))
            except ImportError:  # pragma: no cover - tensorboard is in requirements-train.txt
                self._tb = None
        self._t0 = time.perf_counter()

    def log(self, metrics: dict[str, float], frames: int) -> None:
        wall = time.perf_counter() - self._t0
        for key, value in metrics.items():
            value = float(value)
            self._csv.writerow([frames, f"{wall:.3f}", key, f"{value:.6g}"])
            if self._tb is not None:
                self._tb.add_scalar(key, value, frames)
        self._file.flush()

    def close(self) -> None:
        self._file.close()
        if self._tb is not None:
            self._tb.close()


class EpisodeTracker:
    """Running returns per sub-env across collector batches; ended episodes' stats."""

    def __init__(self, num_envs: int):
        self.returns = np.zeros(num_envs)
        self.lengths = np.zeros(num_envs, dtype=np.int64)
        self.recent: list[dict[str, float]] = []

    def update(self, data: TensorDictBase) -> list[dict[str, float]]:
        """``data`` is a collector batch ``[K, T]``; returns the episodes that ended in it."""
        nxt = data["next"]
        reward = nxt["reward"].reshape(data.shape[0], data.shape[1]).cpu().numpy()
        done = nxt["done"].reshape(data.shape[0], data.shape[1]).cpu().numpy()
        ended = []
        for t in range(data.shape[1]):
            self.returns += reward[:, t]
            self.lengths += 1
            for k in np.flatnonzero(done[:, t]):
                ep = {"return": float(self.returns[k]), "length": int(self.lengths[k])}
                for key in EPISODE_FLAG_KEYS + EPISODE_FLOAT_KEYS:
                    ep[key.removeprefix("episode_")] = float(nxt[key][k, t])
                ended.append(ep)
                self.returns[k] = 0.0
                self.lengths[k] = 0
        self.recent = (self.recent + ended)[-100:]
        return ended


def save_checkpoint(path: Path, cfg, actor, update, counters, buffer=None) -> None:
    """Everything a run needs to continue in a new process: config, actor (what ``evaluate``
    loads), the learner (critics, targets, temperature), its optimisers, counters, torch RNG
    and optionally the replay buffer (written beside the checkpoint)."""
    path.parent.mkdir(parents=True, exist_ok=True)
    state = {
        "config": cfg.to_dict(),
        "actor": actor.state_dict(),
        "learner": update.state_dict(),
        "optimizers": update.optimizer_state(),
        "counters": dict(counters),
        "torch_rng": torch.get_rng_state(),
    }
    if buffer is not None:
        buf_dir = path.with_suffix(".buffer")
        buffer.dumps(buf_dir)
        state["buffer_dir"] = str(buf_dir)
    tmp = path.with_suffix(".tmp")
    torch.save(state, tmp)
    tmp.replace(path)


def train(cfg: TrainConfig, resume: str | None = None) -> dict[str, Any]:
    """Runs SAC on ``cfg``; returns the final counters and the last evaluation summary."""
    log_dir = Path(cfg.log_dir)
    log_dir.mkdir(parents=True, exist_ok=True)
    (log_dir / "config.json").write_text(json.dumps(cfg.to_dict(), indent=2))

    # ---- counters, possibly from a checkpoint
    ckpt = torch.load(resume, map_location=cfg.device, weights_only=False) if resume else None
    counters = {"frames": 0, "updates": 0, "episodes": 0, "iterations": 0, "clone_steps": 0}
    if ckpt is not None:
        counters.update(ckpt["counters"])
    prior = make_prior(cfg)  # RLPD's prior data (refused here if of another world)
    seed_everything(cfg.seed + counters["frames"])
    if cfg.num_threads:
        torch.set_num_threads(cfg.num_threads)

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
    num_updates = max(1, int(cfg.batch_frames * cfg.utd_ratio))
    next_eval = _next_multiple(counters["frames"], cfg.eval_interval)
    next_ckpt = _next_multiple(counters["frames"], cfg.checkpoint_interval)

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
        if ended:
            metrics["train/episode_return"] = float(np.mean([e["return"] for e in ended]))
            metrics["train/episode_length"] = float(np.mean([e["length"] for e in ended]))
            for key in (
                "success",
                "collision",
                "timeout",
                "avg_speed",
                "avg_abs_jerk",
                "max_abs_acc",
            ):
                metrics[f"train/{key}"] = float(np.mean([e[key] for e in ended]))
        metrics["train/episodes"] = counters["episodes"]
        logger.log(metrics, counters["frames"])
        recent = tracker.recent
        pbar.update(frames)
        pbar.set_postfix(
            fps=f"{metrics['train/fps']:.0f}",
            ret=f"{np.mean([e['return'] for e in recent]):.1f}" if recent else "-",
            succ=f"{np.mean([e['success'] for e in recent]):.2f}" if recent else "-",
            env=f"{metrics['train/env_time_share_cum']:.2f}",
        )

        # ---- evaluate, checkpoint
        if cfg.eval_interval and counters["frames"] >= next_eval:
            next_eval = _next_multiple(counters["frames"], cfg.eval_interval)
            last_eval = evaluate_split(cfg, actor, cfg.eval_split)["summary"]
            logger.log({f"eval/{k}": v for k, v in last_eval.items()}, counters["frames"])
        if cfg.checkpoint_interval and counters["frames"] >= next_ckpt:
            next_ckpt = _next_multiple(counters["frames"], cfg.checkpoint_interval)
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


def _next_multiple(frames: int, interval: int) -> int:
    return (frames // interval + 1) * interval if interval else sys.maxsize


def _checkpoint(log_dir, cfg, actor, update, counters, buffer) -> None:
    d = log_dir / "checkpoints"
    save_checkpoint(d / f"step_{counters['frames']}.pt", cfg, actor, update, counters)
    # The replay buffer goes with last.pt only: it is what a resumed run continues from.
    save_checkpoint(
        d / "last.pt", cfg, actor, update, counters, buffer if cfg.save_buffer else None
    )


def main(argv: Sequence[str] | None = None) -> int:
    ap = command_parser("python -m sharedspace.train", __doc__)
    ap.add_argument("--config", default=None, help="TOML or JSON file of TrainConfig fields")
    add_overrides_argument(ap, "overrides")
    ap.add_argument("--resume", default=None, help="checkpoint to continue from")
    args = ap.parse_args(argv)
    if args.resume:  # the checkpoint's config, then the file and the overrides over it
        cfg = TrainConfig.from_dict(torch.load(args.resume, weights_only=False)["config"])
        if args.config:
            cfg = apply_overrides(cfg, _read_table(args.config))
        cfg = apply_overrides(cfg, args.set)
    else:
        cfg = load_config(args.config, args.set)
    out = train(cfg, resume=args.resume)
    print(json.dumps({k: v for k, v in out.items()}, default=float))
    return 0


if __name__ == "__main__":
    sys.exit(main())
