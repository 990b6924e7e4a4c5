"""The actor of any single-car checkpoint, built with no server running.

The algorithms themselves are registered in :mod:`sharedspace.train.registry`; this module
only turns a checkpoint (:func:`~sharedspace.train.checkpoint.read_checkpoint`, the one reader)
into the policy its algorithm's ``make_actor`` builds, its weights loaded."""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path
from types import ModuleType
from typing import Any

import torch
from tensordict import TensorDict
from torchrl.data import Bounded

from sharedspace.names import NODE_FEATURES
from sharedspace.train.checkpoint import read_checkpoint
from sharedspace.train.config import ConfigError, TrainConfig, apply_overrides
from sharedspace.train.registry import UnknownAlgorithm, get_algorithm

__all__ = ["ACTION_SPEC", "learner", "load_checkpoint_actor", "observation_example"]

#: Every car's action: ``[acceleration, yaw rate]`` normalised to ``[-1, 1]`` (ENV_CONTRACT.md).
ACTION_SPEC = Bounded(low=-1.0, high=1.0, shape=(2,), dtype=torch.float32)


def learner(algorithm: str) -> ModuleType:
    """The module implementing the one-car ``algorithm`` (its ``make_actor``)."""
    try:
        return get_algorithm(algorithm, cars="one").load()
    except UnknownAlgorithm as err:
        raise ConfigError(str(err)) from None


def observation_example(max_agents: int, batch: int = 1) -> TensorDict:
    """A batch of empty observations of ``max_agents`` nodes (only the ego present): what a
    network's shapes are materialised on without a server."""
    mask = torch.zeros(batch, max_agents, dtype=torch.bool)
    mask[:, 0] = True
    return TensorDict(
        {
            "features": torch.zeros(batch, max_agents, NODE_FEATURES),
            "adjacency": torch.zeros(batch, max_agents, max_agents),
            "mask": mask,
        },
        batch_size=[batch],
    )


def load_checkpoint_actor(
    path: str | Path | dict[str, Any], overrides: Sequence[str] = (), device: str = "cpu"
):
    """(config, actor) of a one-car checkpoint (a path, or a dict :func:`read_checkpoint`
    returned), its weights loaded; no server is started."""
    ckpt = path if isinstance(path, dict) else read_checkpoint(path, device)
    cfg = apply_overrides(TrainConfig.from_dict(ckpt["config"]), list(overrides))
    cfg = apply_overrides(cfg, {"device": device})
    action = ckpt.get("specs", {}).get("action")  # checkpoints before the specs: the contract's
    spec = ACTION_SPEC if action is None else Bounded(**action, dtype=torch.float32)
    actor = learner(cfg.algorithm).make_actor(cfg, spec)
    with torch.no_grad():  # materialise lazy shapes, if any
        actor(observation_example(cfg.world.max_agents).to(device))
    actor.load_state_dict(ckpt["actor"])
    return cfg, actor
