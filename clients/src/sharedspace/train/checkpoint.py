"""One checkpoint format for every learner: what a run needs to continue in a new process and
what a benchmark needs to know what it is scoring.

A checkpoint is a ``torch.save`` dict with:

- ``format`` (:data:`FORMAT`), ``algorithm`` (``sac``, ``ppo``, ``mappo``, ``ippo``,
  ``masac``), ``network`` (the variant, or the multi-car learner's MLP) and ``world`` (pool,
  world parameters, M, crowd, cars, variations and the reward it was trained under);
- ``config``: the whole config, as ``to_dict`` wrote it;
- ``actor``: the policy's state dict (what an evaluation loads);
- ``learner`` and ``optimizers``: the rest of the learner (critics, targets, temperature) and
  its optimisers' states, for resuming;
- ``counters`` (frames, updates, ...) and ``torch_rng``.

Checkpoints written before ``format`` existed (SAC only) load as ``algorithm`` ``sac``.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import torch

__all__ = ["FORMAT", "describe", "load_checkpoint", "save_checkpoint"]

#: The version of this layout.
FORMAT = 2


def save_checkpoint(
    path: Path,
    cfg,
    actor,
    learner,
    counters: dict[str, Any],
    buffer=None,
    *,
    network: str | None = None,
    world: dict[str, Any] | None = None,
) -> None:
    """Writes ``path`` atomically. ``cfg`` is the run's config (its ``algorithm``, ``variant``
    and ``world()`` name what the checkpoint holds unless ``network`` / ``world`` say it);
    ``learner`` has ``state_dict()`` and ``optimizer_state()``; ``buffer`` (a replay buffer) is
    written beside the checkpoint if given."""
    path.parent.mkdir(parents=True, exist_ok=True)
    state = {
        "format": FORMAT,
        "algorithm": cfg.algorithm,
        "network": network or getattr(cfg, "variant", ""),
        "world": world if world is not None else cfg.world(),
        "config": cfg.to_dict(),
        "actor": actor.state_dict(),
        "learner": learner.state_dict(),
        "optimizers": learner.optimizer_state(),
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


def load_checkpoint(path: str | Path, device: str = "cpu") -> dict[str, Any]:
    """A checkpoint's dict, with ``algorithm`` filled in for the SAC checkpoints written before
    the format had it."""
    ckpt = torch.load(path, map_location=device, weights_only=False)
    if not isinstance(ckpt, dict) or "config" not in ckpt or "actor" not in ckpt:
        raise ValueError(f"{path} is not a sharedspace checkpoint (no config and actor)")
    ckpt.setdefault("format", 1)
    ckpt.setdefault("algorithm", ckpt["config"].get("algorithm", "sac"))
    ckpt.setdefault("network", ckpt["config"].get("variant", ""))
    return ckpt


def describe(ckpt: dict[str, Any]) -> str:
    """One line: algorithm, network, frames."""
    frames = ckpt.get("counters", {}).get("frames", "?")
    return f"{ckpt['algorithm']} / {ckpt['network']}, {frames} frames"
