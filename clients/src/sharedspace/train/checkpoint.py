"""One checkpoint format for every learner: what a run needs to continue in a new process and
what a benchmark needs to know what it is scoring.

A checkpoint is a ``torch.save`` dict with:

- ``specs``: what an actor is built from with no env (nodes, features, the action's shape and
  bounds);
- ``modules``: the plug-in modules (outside this package) that registered its algorithm and
  network, imported by :func:`read_checkpoint` before anything else;
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

import importlib
import json
import pickle
from pathlib import Path
from typing import Any

import torch

from sharedspace.cli import UserError
from sharedspace.names import NODE_FEATURES
from sharedspace.train.networks import NETWORKS, UnknownNetwork, canonical_network
from sharedspace.train.registry import ALGORITHMS, get_algorithm

__all__ = [
    "FORMAT",
    "NotACheckpoint",
    "describe",
    "last_checkpoint",
    "read_checkpoint",
    "save_checkpoint",
    "ship",
]

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
    network = network or getattr(cfg, "network", "")
    state = {
        "format": FORMAT,
        "algorithm": cfg.algorithm,
        "modules": plugin_modules(cfg.algorithm, network),
        "specs": actor_specs(cfg),
        "network": network,
        "world": world if world is not None else cfg.world_record(),
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


#: What a checkpoint that names no algorithm was written by: the SAC trainer (format 1) or, with a
#: crossing task's world, the multi-car MAPPO trainer of its first version.
LEGACY_ALGORITHMS = {False: "sac", True: "mappo"}


def actor_specs(cfg) -> dict[str, Any]:
    """What an actor needs to be built with no env at hand: each car's observation (nodes,
    features per node) and action (its shape and bounds, ENV_CONTRACT.md)."""
    return {
        "max_agents": int(cfg.world.max_agents),
        "node_features": NODE_FEATURES,
        "action": {"shape": [2], "low": -1.0, "high": 1.0},
    }


def plugin_modules(algorithm: str, network: str) -> list[str]:
    """The modules from outside this package that registered ``algorithm`` and ``network``:
    what a reader imports first, so that a plug-in's checkpoint loads with no other step."""
    found = []
    algo = ALGORITHMS.get(algorithm)
    if algo is not None:
        found.append(algo.module if isinstance(algo.module, str) else algo.module.__name__)
    net = NETWORKS.get(network)
    if net is not None:
        found.append(net.make_encoder.__module__)
    return sorted({m for m in found if m and not m.startswith("sharedspace.")})


def last_checkpoint(log_dir: str | Path) -> str | None:
    """The checkpoint a bare ``--resume`` continues from: ``log_dir/checkpoints/last.pt`` if a
    run wrote one there, else None (a fresh run). The one resume path of every trainer."""
    last = Path(log_dir) / "checkpoints" / "last.pt"
    return str(last) if last.is_file() else None


class NotACheckpoint(UserError):
    """A file that no sharedspace learner wrote."""


def read_checkpoint(path: str | Path, device: str = "cpu") -> dict[str, Any]:
    """Any checkpoint a learner wrote, as one dict: ``algorithm``, ``network``, ``world``,
    ``config``, ``actor``, ``counters`` always present. The one reader of checkpoint files:

    - the current format (:data:`FORMAT`), and format 1 (SAC only, no ``algorithm``);
    - a shipped policy (the learner state dropped, :func:`ship`);
    - a multi-car run's ``policy.pt`` (the actor's weights alone, its run's ``config.json``
      beside it: ``{"config": ..., "task": ...}``);
    - multi-car configs from before the algorithm was recorded (read as ``mappo``).

    The network is recorded under its registered name where the config names it."""
    path = Path(path)
    if not path.is_file():
        raise NotACheckpoint(f"{path}: no such checkpoint")
    try:
        ckpt = torch.load(path, map_location=device, weights_only=False)
    except (pickle.UnpicklingError, EOFError, RuntimeError, ValueError, AttributeError) as err:
        first = str(err).strip().splitlines()[0] if str(err).strip() else type(err).__name__
        raise NotACheckpoint(f"{path} is not a sharedspace checkpoint ({first})") from err
    beside = path.parent / "config.json"
    if isinstance(ckpt, dict) and "actor" not in ckpt and beside.is_file():
        run = json.loads(beside.read_text())
        if "task" in run and "config" in run:
            ckpt = {"actor": ckpt, "config": run["config"], "world": {"task": run["task"]}}
    if not isinstance(ckpt, dict) or "config" not in ckpt or "actor" not in ckpt:
        raise NotACheckpoint(f"{path} is not a sharedspace checkpoint (no config and actor)")
    for module in ckpt.get("modules", []):  # plug-ins register their algorithm and network
        try:
            importlib.import_module(module)
        except ImportError as err:
            raise NotACheckpoint(
                f"{path} was written by a plug-in learner ({module}) that cannot be imported "
                f"here: {err}"
            ) from None
    config = ckpt["config"]
    world = ckpt.get("world") or {}
    multi_car = isinstance(world.get("task"), dict)  # the crossing task's fields
    algorithm = ckpt.get("algorithm") or config.get("algorithm") or LEGACY_ALGORITHMS[multi_car]
    if multi_car and not get_algorithm(algorithm).drives(cars=2):
        algorithm = LEGACY_ALGORITHMS[True]  # a multi-car config from before it kept its own
    ckpt["format"] = ckpt.get("format", 1)
    ckpt["algorithm"] = algorithm
    ckpt["world"] = world
    ckpt.setdefault("counters", {})
    network = ckpt.get("network") or config.get("network") or config.get("variant", "")
    try:
        network = canonical_network(network)
    except UnknownNetwork:
        pass  # a multi-car network's description, or a network this process has not registered
    ckpt["network"] = network
    return ckpt


def ship(ckpt: dict[str, Any], path: str | Path) -> Path:
    """Writes ``ckpt`` without its learner state (critics, optimisers, random state): the
    policy a result names. Algorithm, network, world and config stay."""
    out = {k: v for k, v in ckpt.items() if k not in ("learner", "optimizers", "torch_rng")}
    out.pop("buffer_dir", None)
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    torch.save(out, path)
    return path


def describe(ckpt: dict[str, Any]) -> str:
    """One line: algorithm, network, frames."""
    frames = ckpt.get("counters", {}).get("frames", "?")
    return f"{ckpt['algorithm']} / {ckpt['network']}, {frames} frames"
