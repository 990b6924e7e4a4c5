"""MAPPO, IPPO and MASAC on the crossing task: the loop, top to bottom (each algorithm's pieces are
in its own file: :mod:`.mappo` for MAPPO and IPPO, :mod:`.masac`).

    python -m sharedspace.train --set algorithm=mappo seed=0 [--resume [CKPT]]
    python -m sharedspace.marl --set seed=0        # the same, algorithm=mappo by default

TorchRL's ``sota-implementations/multiagent`` scripts (mappo_ippo.py, sac.py) over a live server:
the cars of :class:`~sharedspace.marl.task.CrossingTask` are one agent group of
:class:`~sharedspace.torchrl_multiagent.RemoteMultiAgentEnv`; each car's policy is a
``MultiAgentMLP`` over its own observation (its node features, flattened), one set of weights
for every car; its action is a residual over the car-aware script (``base_driver``). MAPPO's
critic sees every car's observation (centralised), IPPO's only the car's own; MASAC's two
Q-critics are centralised. Writes ``config.json``, ``metrics.csv`` (``train/*`` per collected
batch, ``eval/*`` on the validation scenes every ``eval_interval`` frames: curves, never used to
pick a policy), ``checkpoint.pt`` (resumable) and ``eval.json`` (the final policy's per-car rows
on ``eval_split``: the validation scenes, or the test scenes where the table asks) into
``log_dir``.
"""

from __future__ import annotations

import json
import sys
import time
from collections.abc import Sequence
from pathlib import Path
from types import ModuleType
from typing import Any

import torch
from tensordict import TensorDictBase
from torchrl.collectors import Collector
from torchrl.envs import TransformedEnv

from sharedspace.marl import mappo, masac
from sharedspace.marl.evaluate import STATUSES, play, policy_act, summarize
from sharedspace.marl.networks import GROUP, make_actor
from sharedspace.marl.task import CrossingTask, make_env
from sharedspace.train.checkpoint import load_checkpoint, save_checkpoint
from sharedspace.train.config import TrainConfig
from sharedspace.train.envs import ResidualAction
from sharedspace.train.metrics import MetricLogger
from sharedspace.train.registry import get_algorithm
from sharedspace.train.run import next_multiple

__all__ = ["ALGORITHM_MODULES", "batch_outcomes", "train", "main"]

#: Each algorithm's module (``make_critic``, ``make_loss``, ``make_optimizer``, ``make_buffer``,
#: ``make_target_update``, ``learn``); MAPPO and IPPO differ only in their critic's input.
ALGORITHM_MODULES: dict[str, ModuleType] = {"mappo": mappo, "ippo": mappo, "masac": masac}


def batch_outcomes(data: TensorDictBase) -> dict[str, float]:
    """``train/*``: per-car episode outcomes that ended in a collected batch, and its reward."""
    nxt = data["next", GROUP]
    ended = sum(int(nxt[f"episode_{s}"].sum()) for s in STATUSES)
    out = {"train/reward": float(nxt["reward"].mean()), "train/car_episodes": float(ended)}
    if ended:
        for s in (*STATUSES, "car_collision"):
            out[f"train/{s}"] = float(nxt[f"episode_{s}"].sum()) / ended
    return out


def _evaluate(task, actor, cfg, client) -> tuple[list[dict[str, Any]], dict[str, Any]]:
    """The policy on ``cfg.eval_split``: the validation scenes (seeds of their own, never
    trained on) or, asked for, the test scenes."""
    split = cfg.eval_split
    names = task.scene_names(split, cfg.validation_scenes if split == "validation" else None)
    act = policy_act(actor, cfg.base_driver, cfg.residual_scale)
    rows = play(task, act, client, split=split, scenes=names)
    return rows, summarize(rows)


def train(cfg: TrainConfig, task: CrossingTask | None = None, resume: bool = False) -> dict:
    """One run of ``cfg.task``'s cars (``task``: another crossing task); returns the final
    evaluation's summary (on ``cfg.eval_split``)."""
    task = task or CrossingTask()
    torch.manual_seed(cfg.seed)
    torch.set_num_threads(max(1, cfg.num_threads))
    log_dir = Path(cfg.log_dir)
    log_dir.mkdir(parents=True, exist_ok=True)
    (log_dir / "config.json").write_text(
        json.dumps({"config": cfg.to_dict(), "task": _task_dict(task)}, indent=1)
    )

    client = cfg.connection().open()
    try:
        return _train(cfg, task, client, log_dir, resume)
    finally:
        client.shutdown()


def _train(cfg, task, client, log_dir: Path, resume: bool) -> dict:
    env = make_env(
        task, "train", cfg.num_envs, client, seed=cfg.seed, reward_weights=cfg.world_reward_weights
    )
    if cfg.base_driver:
        env = TransformedEnv(env, ResidualAction(cfg.base_driver, GROUP, cfg.residual_scale))
    algo = ALGORITHM_MODULES[cfg.algorithm]
    on_policy = get_algorithm(cfg.algorithm).family == "on"
    actor = make_actor(cfg, task)
    critic = algo.make_critic(cfg, task)
    loss = algo.make_loss(cfg, actor, critic)
    optim = algo.make_optimizer(cfg, loss)
    target_update = algo.make_target_update(cfg, loss)

    frames, iteration, wall = 0, 0, 0.0
    ckpt_path = log_dir / "checkpoint.pt"
    learner = LossAndOptimizer(loss, optim)
    if resume and ckpt_path.exists():
        ckpt = load_checkpoint(ckpt_path)
        learner.load(ckpt)
        counters = ckpt["counters"]
        frames, iteration, wall = counters["frames"], counters["iterations"], counters["wall_s"]
    if frames >= cfg.total_frames:
        env.close()
        return json.loads((log_dir / "eval.json").read_text())["summary"]

    batch = cfg.num_envs * cfg.rollout_steps if on_policy else cfg.frames_per_batch
    frames_per_batch = batch - batch % cfg.num_envs
    collector = Collector(
        env,
        actor,
        frames_per_batch=max(frames_per_batch, cfg.num_envs),
        total_frames=cfg.total_frames - frames,
    )
    buffer = algo.make_buffer(cfg, frames_per_batch)
    logger = MetricLogger(log_dir, tensorboard=False)
    next_eval = next_multiple(frames, cfg.eval_interval)
    t0 = time.perf_counter() - wall
    for data in collector:
        frames += data.numel()
        iteration += 1
        metrics = batch_outcomes(data)
        metrics.update(algo.learn(cfg, loss, optim, buffer, data, target_update, frames))
        collector.update_policy_weights_()
        wall = time.perf_counter() - t0
        metrics["train/wall_s"] = wall
        if frames >= next_eval or frames >= cfg.total_frames:
            _, summary = _evaluate(task, actor, cfg, client)
            for key in (*STATUSES, "car_collision"):
                metrics[f"eval/{key}"] = summary[key]["rate"]
            next_eval = next_multiple(frames, cfg.eval_interval)
            counters = {"frames": frames, "iterations": iteration, "wall_s": wall}
            save_checkpoint(
                ckpt_path,
                cfg,
                actor,
                learner,
                counters,
                network=network(cfg),
                world=world(cfg, task),
            )
        logger.log(metrics, frames)
    collector.shutdown()
    rows, summary = _evaluate(task, actor, cfg, client)
    summary["wall_s"] = time.perf_counter() - t0
    summary["frames"] = frames
    torch.save(actor.state_dict(), log_dir / "policy.pt")
    (log_dir / "eval.json").write_text(
        json.dumps({"summary": summary, "rows": rows, "config": cfg.to_dict()}, indent=1)
    )
    logger.close()
    if not env.is_closed:
        env.close()
    return summary


def _task_dict(task: CrossingTask) -> dict[str, Any]:
    return {k: v for k, v in vars(task).items()}


def network(cfg: TrainConfig) -> str:
    """What a checkpoint names the multi-car learners' network: the registered network, or
    the flat observation's MLP."""
    if cfg.network:
        return cfg.network
    widths = "x".join(str(h) for h in cfg.hidden_sizes)
    return f"MultiAgentMLP {widths} (shared: {cfg.share_params})"


def world(cfg: TrainConfig, task: CrossingTask) -> dict[str, Any]:
    """What a checkpoint records of the world: the task and the reward."""
    reward = {"name": cfg.reward, "weights": cfg.world_reward_weights}
    return {"task": _task_dict(task), "reward": reward}


class LossAndOptimizer:
    """A TorchRL loss and its optimiser as :func:`~sharedspace.train.checkpoint.save_checkpoint`
    keeps a learner."""

    def __init__(self, loss: torch.nn.Module, optim: torch.optim.Optimizer):
        self.loss, self.optim = loss, optim

    def state_dict(self) -> dict[str, Any]:
        return self.loss.state_dict()

    def optimizer_state(self) -> dict[str, Any]:
        return {"adam": self.optim.state_dict()}

    def load(self, ckpt: dict[str, Any]) -> None:
        self.loss.load_state_dict(ckpt["learner"])
        self.optim.load_state_dict(ckpt["optimizers"]["adam"])


def main(argv: Sequence[str] | None = None) -> int:
    """``python -m sharedspace.marl``: ``python -m sharedspace.train`` for the multi-car
    algorithms (``algorithm=mappo`` unless the overrides say otherwise)."""
    from sharedspace.train.train import main as train_main

    return train_main(argv, default_algorithm="mappo")


def run_command(cfg: TrainConfig, resume: str | bool | None = None) -> dict[str, Any]:
    """One run from the command line (:func:`sharedspace.train.train.main`): trains, prints the
    per-car outcome, returns the summary."""
    summary = train(cfg, resume=bool(resume))
    print(
        f"{cfg.algorithm} seed {cfg.seed}: per-car success {summary['success']['rate']:.3f}, "
        f"collision {summary['collision']['rate']:.3f}, "
        f"car-car {summary['car_collision']['rate']:.3f} on the {cfg.eval_split} scenes; "
        f"{summary.get('wall_s', 0):.0f} s"
    )
    return summary


if __name__ == "__main__":
    sys.exit(main())
