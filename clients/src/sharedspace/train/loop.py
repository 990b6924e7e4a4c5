"""The one training loop, for every registered algorithm, on-policy or off, one car or several:
collect a batch, learn from it, log, score on the validation split, checkpoint.

What differs between algorithms lives in two objects their module builds (BenchMARL's split of
an experiment into algorithm and task, TorchRL's sota scripts' ``make_*`` factories), whose
contract :mod:`sharedspace.train.protocol` states (``World``, ``Learner``):

- the **world** (``module.make_world(cfg)``): the envs of one car (:class:`OneCar`) or of the
  crossing task's cars (:class:`sharedspace.marl.train.Cars`), how a batch's ended episodes
  are counted, how a policy is scored, what a checkpoint records of the world;
- the **learner** (``module.make_learner(cfg, world, env)``): the actor the collector plays,
  the frames of a batch (and of uniform random actions first, off-policy), and ``step(data,
  counters)``, which learns from one collected batch: PPO's epochs of minibatches over it,
  SAC's replay buffer and its updates per frame. Its ``state_dict`` / ``optimizer_state`` /
  ``load`` are what a checkpoint keeps.

A run writes into ``log_dir``: ``config.json``, ``metrics.csv`` (long format: frames, wall_s,
metric, value; ``train/`` per batch, ``eval/`` on the validation split), TensorBoard events and
``checkpoints/{step_<frames>,last}.pt`` (:mod:`sharedspace.train.checkpoint`). ``train``
returns the counters, the last scoring and where the wall time went (``timing``).
"""

from __future__ import annotations

import contextlib
import os
import time
from pathlib import Path
from typing import Any

import torch
import tqdm
from torchrl.collectors import Collector

from sharedspace.train.checkpoint import read_checkpoint, save_checkpoint
from sharedspace.train.config import TrainConfig
from sharedspace.train.envs import make_env
from sharedspace.train.evaluation import evaluate_split
from sharedspace.train.metrics import (
    EpisodeTracker,
    MetricLogger,
    episode_metrics,
    progress_postfix,
)
from sharedspace.train.overlap import OverlappedCollector
from sharedspace.train.protocol import check_stats
from sharedspace.train.registry import get_algorithm
from sharedspace.train.run import next_multiple, seed_everything, start_run

__all__ = ["Clock", "OneCar", "make_collector", "overlaps", "train"]


def train(cfg: TrainConfig, resume: str | None = None, world=None) -> dict[str, Any]:
    """Runs ``cfg.algorithm`` on ``cfg`` (from the checkpoint ``resume`` if given; in
    ``world`` if given, else the one its module makes)."""
    module = get_algorithm(cfg.algorithm).load()
    log_dir = start_run(cfg)

    # ---- counters, world, env and learner, possibly from a checkpoint
    ckpt = read_checkpoint(resume, cfg.device) if resume else None
    counters = {"frames": 0, "updates": 0, "episodes": 0, "iterations": 0, "lost_episodes": 0}
    counters |= ckpt["counters"] if ckpt is not None else {}
    seed_everything(cfg.seed + counters["frames"])
    world = world if world is not None else module.make_world(cfg)
    env = world.make_env(seed=cfg.seed + counters["frames"])
    learner = module.make_learner(cfg, world, env)
    if ckpt is not None:
        learner.load(ckpt)
    logger = MetricLogger(log_dir)
    clock = Clock(env)
    learner.start(counters, logger)  # SAC: behaviour cloning on prior data, if asked
    last_eval: dict[str, float] = {}
    remaining = max(cfg.total_frames - counters["frames"], 0)
    if remaining == 0:
        env.close()
        logger.close()
        return {"counters": counters, "eval": last_eval, "timing": clock.timing}

    # ---- collect, learn, log, score, checkpoint
    collector = make_collector(cfg, env, learner, remaining, counters["frames"])
    next_eval = next_multiple(counters["frames"], cfg.algo.eval_interval)
    next_ckpt = next_multiple(counters["frames"], cfg.checkpoint_interval)
    pbar = tqdm.tqdm(
        total=cfg.total_frames,
        initial=counters["frames"],
        disable=not cfg.progress,
        unit="fr",
        dynamic_ncols=True,
    )
    try:
        for data in collector:
            clock.collected()
            counters["frames"] += data.numel()
            counters["iterations"] += 1
            outcomes = world.outcomes(data)  # the episodes that ended in the batch
            counters["episodes"] += int(outcomes.pop("ended"))
            counters["lost_episodes"] += int(outcomes.pop("lost"))

            stats = check_stats(learner.step(data, counters))  # its family's update
            collector.update_policy_weights_()
            clock.updated()

            metrics = clock.metrics(data.numel()) | {f"train/{k}": v for k, v in stats.items()}
            metrics |= outcomes | {"train/episodes": counters["episodes"]}
            metrics["train/updates"] = counters["updates"]
            logger.log(metrics, counters["frames"])
            pbar.update(data.numel())
            pbar.set_postfix(progress_postfix(metrics, world.recent()))

            if (
                cfg.algo.eval_interval and counters["frames"] >= next_eval
            ):  # curves: nothing is chosen
                next_eval = next_multiple(counters["frames"], cfg.algo.eval_interval)
                last_eval = _evaluate(world, learner.actor, clock, logger, counters["frames"])
            if cfg.checkpoint_interval and counters["frames"] >= next_ckpt:
                next_ckpt = next_multiple(counters["frames"], cfg.checkpoint_interval)
                _checkpoint(log_dir, cfg, world, learner, counters)
            clock.collecting()
    finally:  # an overlapped collector's thread stops with the run, whatever ended it
        collector.shutdown()
    pbar.close()
    _checkpoint(log_dir, cfg, world, learner, counters)
    if cfg.algo.eval_interval and last_eval.get("frames") != counters["frames"]:  # the run's policy
        last_eval = _evaluate(world, learner.actor, clock, logger, counters["frames"])
    world.finish(learner.actor, log_dir, last_eval, clock.timing)
    logger.close()
    if not env.is_closed:
        env.close()
    return {"counters": counters, "eval": last_eval, "timing": clock.timing}


def make_collector(
    cfg: TrainConfig, env, learner, remaining: int, frames: int
) -> Collector | OverlappedCollector:
    """TorchRL's ``Collector`` of the learner's batches over the ``remaining`` frames (uniform
    random actions first for an off-policy learner's warm-up, ``frames`` into the run);
    done sub-envs are reset through ``step_and_maybe_reset``. With ``overlap`` (on-policy
    learners) it collects one batch ahead in a thread while the learner updates, with a copy
    of the actor one update behind (:class:`~sharedspace.train.overlap.OverlappedCollector`)."""

    def collector(policy) -> Collector:
        return Collector(
            env,
            policy,
            frames_per_batch=learner.batch_frames,
            total_frames=remaining,
            init_random_frames=max(learner.random_frames - frames, 0),
            device=cfg.device,
            env_device="cpu",
            auto_register_policy_transforms=False,  # the policy is not recurrent
        )

    if overlaps(cfg):
        return OverlappedCollector(learner.actor, collector)
    return collector(learner.actor)


def overlaps(cfg: TrainConfig) -> bool:
    """Whether a run of ``cfg`` collects its next batch while it updates: ``overlap`` set, for
    an on-policy learner (an off-policy one's updates per frame are its recipe)."""
    overlap = getattr(cfg.algo, "overlap", False)  # an option of the on-policy algorithms
    return overlap and get_algorithm(cfg.algorithm).family == "on"


def _evaluate(world, actor, clock: Clock, logger: MetricLogger, frames: int) -> dict[str, Any]:
    """The world's scoring of ``actor`` on the config's ``eval_split``, logged as ``eval/*``
    with the training wall time so far."""
    with clock.evaluating():
        summary = world.evaluate(actor) | {"frames": frames}
    numbers = {k: v for k, v in summary.items() if isinstance(v, int | float) and k != "frames"}
    row = {f"eval/{k}": v for k, v in numbers.items()}
    logger.log(row | {"eval/train_wall_s": clock.train_s}, frames)
    return summary


def _checkpoint(log_dir: Path, cfg: TrainConfig, world, learner, counters) -> None:
    d = log_dir / "checkpoints"
    record = {"network": world.network(), "world": world.record()}
    save_checkpoint(
        d / f"step_{counters['frames']}.pt", cfg, learner.actor, learner, counters, **record
    )
    # A replay buffer goes with last.pt only: it is what a resumed run continues from.
    saved = getattr(cfg.algo, "save_buffer", False)  # an option of SAC's
    buffer = getattr(learner, "buffer", None) if saved else None
    save_checkpoint(d / "last.pt", cfg, learner.actor, learner, counters, buffer, **record)


class OneCar:
    """The world of one learning car per env: the batched env of the config
    (:func:`sharedspace.train.envs.make_env`, the residual transform over its base driver), its
    ended episodes (:class:`~sharedspace.train.metrics.EpisodeTracker`), the Table II columns
    on the validation split (:func:`sharedspace.train.evaluation.evaluate_split`)."""

    def __init__(self, cfg: TrainConfig):
        self.cfg = cfg
        self.tracker = EpisodeTracker(cfg.algo.num_envs)

    def make_env(self, seed: int):
        cfg = self.cfg
        return make_env(
            cfg.world,
            "train",
            cfg.algo.num_envs,
            seed,
            variations=cfg.world.variations,
            driving=cfg.driving,
        )

    def outcomes(self, data) -> dict[str, float]:
        ended = self.tracker.update(data)
        out = episode_metrics(ended) | {"train/reward_mean": float(data["next", "reward"].mean())}
        return out | {"ended": len(ended), "lost": sum(e["lost"] for e in ended)}

    def recent(self) -> list[dict[str, float]]:
        return self.tracker.recent

    def evaluate(self, actor) -> dict[str, Any]:
        cfg = self.cfg
        split = cfg.world.eval_split
        return evaluate_split(cfg.world, actor, split, cfg.seed, cfg.driving)["summary"]

    def network(self) -> str:
        return self.cfg.net.network

    def record(self) -> dict[str, Any]:
        return self.cfg.world_record()

    def finish(self, actor, log_dir: Path, summary: dict[str, Any], timing: dict) -> None:
        """Nothing beyond the checkpoints."""


class Clock:
    """Where a run's wall time goes: collection (of it, the env's round trips), updates and
    evaluations, in seconds (``timing``), and each batch's ``train/*`` rates."""

    def __init__(self, env):
        self.env = env
        self.env0 = getattr(env, "env_time_s", 0.0)
        self.timing = {"collect_s": 0.0, "env_s": 0.0, "update_s": 0.0, "eval_s": 0.0}
        self.t_collect = self.t_update = self.t_done = time.perf_counter()

    @property
    def train_s(self) -> float:
        """Collection plus updates: the run's wall time without its evaluations."""
        return self.timing["collect_s"] + self.timing["update_s"]

    def collecting(self) -> None:
        self.t_collect = time.perf_counter()

    def collected(self) -> None:
        self.t_update = time.perf_counter()
        self.timing["collect_s"] += self.t_update - self.t_collect
        self.timing["env_s"] = getattr(self.env, "env_time_s", 0.0) - self.env0

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


def torch_threads(n: int) -> None:
    """Sets torch's CPU threads (0: every core)."""
    torch.set_num_threads(n or os.cpu_count() or 1)
