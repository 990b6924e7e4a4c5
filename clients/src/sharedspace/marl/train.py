"""Several learning cars per env, as the one training loop (:mod:`sharedspace.train.loop`)
drives them: the crossing task's world (:class:`Cars`) and the learner every multi-car
algorithm shares (:class:`CarsLearner`), after TorchRL's ``sota-implementations/multiagent``
scripts (mappo_ippo.py, sac.py).

    python -m sharedspace.train --set algorithm=mappo seed=0 [--resume [CKPT]]
    python -m sharedspace.marl --set seed=0        # the same, algorithm=mappo by default

The cars of :class:`~sharedspace.marl.task.CrossingTask` are one agent group of
:class:`~sharedspace.torchrl_multiagent.RemoteMultiAgentEnv`; each car's policy is a
``MultiAgentMLP`` over its own observation (its node features flattened, or a registered
network's encoding, :mod:`sharedspace.marl.networks`), one set of weights for every car; its
action is a residual over the car-aware script (``base_driver``). What differs between the
algorithms is in their modules: :mod:`.mappo` (MAPPO's centralised critic, IPPO's own),
:mod:`.masac` (centralised Q-critics, off-policy), each ``make_critic``, ``make_loss``,
``make_optimizer``, ``make_buffer``, ``make_target_update`` and ``learn``.

Besides what every run writes (:mod:`sharedspace.train.loop`; ``eval/*`` on the validation
scenes, seeds of their own, never trained on), a run writes ``eval.json`` (the final policy's
per-car rows on ``eval_split``: the validation scenes, or the test scenes where the table asks)
and ``policy.pt`` (the actor's weights) into ``log_dir``.
"""

from __future__ import annotations

import json
import sys
from collections.abc import Sequence
from pathlib import Path
from types import ModuleType
from typing import Any

import torch
from tensordict import TensorDictBase
from torchrl.envs import TransformedEnv

from sharedspace.cli import run_command
from sharedspace.marl.evaluate import STATUSES, play, policy_act, summarize
from sharedspace.marl.networks import GROUP, make_actor
from sharedspace.marl.task import CrossingTask, make_env
from sharedspace.train.checkpoint import last_checkpoint
from sharedspace.train.config import TrainConfig
from sharedspace.train.envs import ResidualAction
from sharedspace.train.loop import train as train_loop
from sharedspace.train.registry import get_algorithm

__all__ = ["Cars", "CarsLearner", "batch_outcomes", "learner_of", "train", "main"]


def batch_outcomes(data: TensorDictBase) -> dict[str, float]:
    """``train/*``: per-car episode outcomes that ended in a collected batch, and its reward."""
    nxt = data["next", GROUP]
    ended = sum(int(nxt[f"episode_{s}"].sum()) for s in STATUSES)
    out = {"train/reward": float(nxt["reward"].mean()), "train/car_episodes": float(ended)}
    if ended:
        for s in (*STATUSES, "car_collision"):
            out[f"train/{s}"] = float(nxt[f"episode_{s}"].sum()) / ended
    return out


class Cars:
    """The world of the crossing task's cars: its envs in TorchRL's multi-agent layout (the
    residual transform over ``base_driver`` on the group's actions), the per-car outcomes of a
    batch, the per-car scoring on ``eval_split``, and what a checkpoint records of it."""

    def __init__(self, cfg: TrainConfig, task: CrossingTask | None = None):
        self.cfg = cfg
        self.task = task or CrossingTask()
        self.client = cfg.world.connection().open()
        self.rows: list[dict[str, Any]] = []
        self.summary: dict[str, Any] = {}

    def make_env(self, seed: int):
        cfg = self.cfg
        weights = cfg.reward_weights
        env = make_env(
            self.task, "train", cfg.algo.num_envs, self.client, seed=seed, reward_weights=weights
        )
        if not cfg.algo.base_driver:
            return env
        return TransformedEnv(
            env, ResidualAction(cfg.algo.base_driver, GROUP, cfg.algo.residual_scale)
        )

    def outcomes(self, data: TensorDictBase) -> dict[str, float]:
        out = batch_outcomes(data)
        nxt = data["next", GROUP]
        # a sub-env cut short by a lost server: truncated, with none of the outcomes
        outcome = sum(nxt[f"episode_{s}"] for s in STATUSES).bool()
        lost = (nxt["truncated"].bool() & ~outcome).sum()
        return out | {"ended": out["train/car_episodes"] + float(lost), "lost": float(lost)}

    def recent(self) -> list[dict[str, float]]:
        return []

    def evaluate(self, actor) -> dict[str, float]:
        """Every car of the ``eval_split`` scenes (``validation_scenes`` of the validation
        seeds, or the test scenes): the per-car rates."""
        cfg = self.cfg
        split = cfg.world.eval_split
        names = self.task.scene_names(
            split, cfg.world.validation_scenes if split == "validation" else None
        )
        act = policy_act(actor, cfg.algo.base_driver, cfg.algo.residual_scale)
        self.rows = play(self.task, act, self.client, split=split, scenes=names)
        self.summary = summarize(self.rows)
        rates = {k: self.summary[k]["rate"] for k in (*STATUSES, "car_collision")}
        return rates | {"car_episodes": self.summary["car_episodes"]}

    def network(self) -> str:
        """The registered network, or the flat observation's MLP."""
        cfg = self.cfg
        if cfg.net.network:
            return cfg.net.network
        widths = "x".join(str(h) for h in cfg.algo.hidden_sizes)
        return f"MultiAgentMLP {widths} (shared: {cfg.algo.share_params})"

    def record(self) -> dict[str, Any]:
        """The task (every field) and the reward."""
        reward = {"name": self.cfg.algo.reward, "weights": self.cfg.reward_weights}
        return {"task": dict(vars(self.task)), "reward": reward}

    def finish(self, actor, log_dir: Path, summary: dict[str, Any], timing: dict) -> None:
        """``policy.pt`` and ``eval.json`` (the last scoring's rows), then the connection
        closes."""
        self.summary |= {"wall_s": sum(timing.values()) - timing["env_s"]}
        self.summary["frames"] = summary.get("frames")
        torch.save(actor.state_dict(), log_dir / "policy.pt")
        doc = {"summary": self.summary, "rows": self.rows, "config": self.cfg.to_dict()}
        (log_dir / "eval.json").write_text(json.dumps(doc, indent=1))
        self.client.shutdown()


class CarsLearner:
    """Every multi-car algorithm as the training loop drives it: the shared actor, its
    module's critic, TorchRL loss, optimiser, buffer and target update, and its ``learn`` per
    collected batch (on-policy: ``num_envs x rollout_steps`` frames; off-policy:
    ``frames_per_batch``)."""

    def __init__(self, cfg: TrainConfig, world: Cars, algo: ModuleType):
        self.cfg, self.algo = cfg, algo
        self.actor = make_actor(cfg, world.task)
        critic = algo.make_critic(cfg, world.task)
        self.loss = algo.make_loss(cfg, self.actor, critic)
        self.optim = algo.make_optimizer(cfg, self.loss)
        self.target_update = algo.make_target_update(cfg, self.loss)
        on_policy = get_algorithm(cfg.algorithm).family == "on"
        batch = (
            cfg.algo.num_envs * cfg.algo.rollout_steps if on_policy else cfg.algo.frames_per_batch
        )
        self.batch_frames = max(batch - batch % cfg.algo.num_envs, cfg.algo.num_envs)
        self.random_frames = 0
        self.buffer = algo.make_buffer(cfg, self.batch_frames)

    def start(self, counters: dict[str, Any], logger) -> None:
        """Nothing before the first batch."""

    def step(self, data: TensorDictBase, counters: dict[str, Any]) -> dict[str, float]:
        cfg, algo = self.cfg, self.algo
        stats = algo.learn(
            cfg, self.loss, self.optim, self.buffer, data, self.target_update, counters["frames"]
        )
        counters["updates"] += int(stats.pop("gradient_steps"))
        return stats

    def state_dict(self) -> dict[str, Any]:
        return self.loss.state_dict()

    def optimizer_state(self) -> dict[str, Any]:
        return {"adam": self.optim.state_dict()}

    def load(self, ckpt: dict[str, Any]) -> None:
        self.actor.load_state_dict(ckpt["actor"])
        self.loss.load_state_dict(ckpt["learner"])
        self.optim.load_state_dict(ckpt["optimizers"]["adam"])
        if "torch_rng" in ckpt:
            torch.set_rng_state(ckpt["torch_rng"])


def learner_of(module_name: str):
    """``make_learner`` of a multi-car algorithm's module: a :class:`CarsLearner` over that
    module's critic, loss and update."""

    def make_learner(cfg: TrainConfig, world: Cars, env) -> CarsLearner:
        return CarsLearner(cfg, world, sys.modules[module_name])

    return make_learner


def train(
    cfg: TrainConfig, task: CrossingTask | None = None, resume: str | bool | None = None
) -> dict[str, Any]:
    """One run of the crossing task's cars (``task``: another crossing task) through the one
    training loop; ``resume``: a checkpoint, or True for ``log_dir``'s last one. Returns the
    final scoring's per-car summary (on ``eval_split``)."""
    if resume is True:
        resume = last_checkpoint(cfg.log_dir)
    world = Cars(cfg, task)
    out = train_loop(cfg, resume or None, world=world)
    if not world.summary:  # nothing left to train: the last run's record
        world.client.shutdown()
        return json.loads((Path(cfg.log_dir) / "eval.json").read_text())["summary"]
    return world.summary | {"counters": out["counters"]}


def main(argv: Sequence[str] | None = None) -> int:
    """``python -m sharedspace.marl``: ``python -m sharedspace.train`` for the multi-car
    algorithms (``algorithm=mappo`` unless the overrides say otherwise)."""
    from sharedspace.train.train import main as train_main

    return train_main(argv, default_algorithm="mappo")


if __name__ == "__main__":
    sys.exit(run_command(main))
