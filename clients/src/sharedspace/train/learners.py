"""The single-car algorithms by name, and the actor of any checkpoint.

A new algorithm is a module beside :mod:`.sac` and :mod:`.ppo` with ``make_actor(cfg,
action_spec)`` (the policy an evaluation plays) and ``train(cfg, resume=None)`` (its loop),
registered here and in :data:`sharedspace.train.config.ALGORITHMS` (docs/ARCHITECTURE.md,
"Adding an algorithm")."""

from __future__ import annotations

from collections.abc import Sequence
from types import ModuleType

import torch

from sharedspace.train import ppo, sac
from sharedspace.train.checkpoint import load_checkpoint
from sharedspace.train.config import ConfigError, TrainConfig, apply_overrides
from sharedspace.train.envs import make_env

__all__ = ["LEARNERS", "learner", "load_checkpoint_actor"]

#: Every single-car algorithm's module.
LEARNERS: dict[str, ModuleType] = {"sac": sac, "ppo": ppo}


def learner(algorithm: str) -> ModuleType:
    """The module of ``algorithm``."""
    if algorithm not in LEARNERS:
        raise ConfigError(f"algorithm must be one of {tuple(LEARNERS)}, not {algorithm!r}")
    return LEARNERS[algorithm]


def load_checkpoint_actor(path: str, overrides: Sequence[str] = (), device: str = "cpu"):
    """(config, actor) of a checkpoint written by either single-car algorithm."""
    ckpt = load_checkpoint(path, device)
    cfg = apply_overrides(TrainConfig.from_dict(ckpt["config"]), list(overrides))
    cfg = apply_overrides(cfg, {"device": device})
    probe = make_env(cfg, split=cfg.eval_split, num_envs=1)
    actor = learner(cfg.algorithm).make_actor(cfg, probe.action_spec_unbatched)
    with torch.no_grad():
        actor(probe.reset())  # materialise lazy shapes, if any
    actor.load_state_dict(ckpt["actor"])
    probe.close()
    return cfg, actor
