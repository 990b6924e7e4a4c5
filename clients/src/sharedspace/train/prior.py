"""Prior data: transitions recorded before training (demonstrations), their on-disk format,
and how the learner uses them (RLPD, Ball et al. 2023: every batch half prior, half online).

**Format** (version :data:`VERSION`). A directory holding

- ``header.json``: ``format``, ``version``, the ``world`` the transitions were recorded in
  (:func:`world_of`: the pool's and the world parameters' SHA-256, the observation layout,
  the pedestrian and vehicle models, the reward weights, the protocol version), the ``sources``
  (name -> what recorded it, its episodes, transitions and success share), the date and the
  command;
- ``transitions/``: a memory-mapped :class:`~tensordict.TensorDict` (TorchRL's storage format,
  ``TensorDict.load_memmap``) of ``N`` transitions in the replay buffer's layout
  (:data:`KEYS`: ``features``, ``adjacency``, ``mask``, ``action`` and ``next``'s
  ``features``, ``adjacency``, ``mask``, ``reward``, ``terminated``, ``done``) plus the
  labels of :data:`LABELS` (``source`` indexes ``header["sources"]`` in order; the
  ``episode_success`` of a transition is its episode's outcome).

:func:`load_prior` refuses a dataset recorded in another world than the trainer's with
:class:`PriorDataError` naming each field that differs. The datasets are written by
:mod:`sharedspace.paper.demos` (``make demos``).

**Mirror augmentation.** Reflecting the world about the ego's axis is a symmetry of the
simulator (model.md 10: the seeded variations mirror scenes): it negates the lateral
observation features (``rel_y``, ``rel_vy``, ``heading_diff``, ``goal_dy``) and the yaw
rate, and leaves the risk graph, the mask and the reward as they are (distances, speeds and
clearances do not change). :func:`mirrored` applies it; the sampler mirrors a random half of
every prior batch instead of storing both copies.
"""

from __future__ import annotations

import hashlib
import json
import time
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import torch
from tensordict import TensorDict, TensorDictBase
from torch import nn

from sharedspace.cli import UserError
from sharedspace.names import FEATURE_NAMES, REWARD_TERMS, Feature
from sharedspace.pool import DEFAULT_POOL_PATH
from sharedspace.scripted import SCRIPTED
from sharedspace.train.config import TrainConfig
from sharedspace.wire import PROTOCOL_VERSION
from sharedspace.world_config import WorldConfig

__all__ = [
    "FORMAT",
    "VERSION",
    "KEYS",
    "LABELS",
    "PriorDataError",
    "PriorData",
    "world_of",
    "write_prior",
    "load_prior",
    "mirrored",
    "make_prior",
    "mixed_batch",
    "clone",
]

FORMAT = "sharedspace-prior"
VERSION = 1
#: The replay buffer's keys a transition holds (what :mod:`.update` reads).
KEYS: tuple[Any, ...] = (
    "features",
    "adjacency",
    "mask",
    "action",
    ("next", "features"),
    ("next", "adjacency"),
    ("next", "mask"),
    ("next", "reward"),
    ("next", "terminated"),
    ("next", "done"),
)
#: Per-transition labels: recording source, scene (pool index), variation seed (-1: the
#: recorded scene), episode number within the dataset, step within it, and whether the
#: episode ended at the goal.
LABELS = ("source", "scenario_index", "variation", "episode", "step", "episode_success")
#: Observation features that change sign under the mirror (lateral coordinates, headings).
MIRRORED_FEATURES = (Feature.REL_Y, Feature.REL_VY, Feature.HEADING_DIFF, Feature.GOAL_DY)
#: The action component that changes sign under the mirror (the yaw rate).
MIRRORED_ACTION = 1


class PriorDataError(UserError):
    """A prior dataset that cannot serve this trainer: not a dataset, another format version,
    or recorded in another world (the message names each differing field)."""


def _sha256(path: str | Path) -> str:
    return hashlib.sha256(Path(path).read_bytes()).hexdigest()


def world_of(world: WorldConfig, reward_weights: dict[str, float]) -> dict[str, Any]:
    """What a transition means in ``world`` under ``reward_weights``: the scenario pool and the
    world parameters (their files' SHA-256), the observation layout and the reward. Two worlds
    with the same identity produce the same transitions for the same actions."""
    pool = Path(world.scenario_pool) if world.scenario_pool else DEFAULT_POOL_PATH
    return {
        "pool": {"file": pool.name, "sha256": _sha256(pool)},
        "params": {
            "file": Path(world.server_params).name if world.server_params else "",
            "sha256": _sha256(world.server_params) if world.server_params else "defaults",
        },
        "max_agents": world.max_agents,
        "feature_names": list(FEATURE_NAMES),
        "pedestrian_model": world.pedestrian_model,
        "vehicle_model": world.vehicle_model,
        "reward_terms": list(REWARD_TERMS),
        "reward_weights": dict(sorted(reward_weights.items())),
        "protocol_version": PROTOCOL_VERSION,
    }


def _differences(recorded: Any, wanted: Any, path: str = "world") -> list[str]:
    if isinstance(recorded, dict) and isinstance(wanted, dict):
        out = []
        for key in sorted(set(recorded) | set(wanted)):
            out += _differences(recorded.get(key), wanted.get(key), f"{path}.{key}")
        return out
    return [] if recorded == wanted else [f"{path}: dataset {recorded!r}, trainer {wanted!r}"]


class PriorData:
    """A loaded dataset: ``transitions`` (memory-mapped, :data:`KEYS` + :data:`LABELS`) and
    its ``header``; :meth:`sample` draws a batch."""

    def __init__(self, transitions: TensorDictBase, header: dict[str, Any], path: str):
        self.transitions, self.header, self.path = transitions, header, path
        self._data = transitions.select(*KEYS)

    def __len__(self) -> int:
        return self.transitions.shape[0]

    def select(self, sources: Sequence[str] = (), successes_only: bool = False) -> PriorData:
        """The transitions of the named ``sources`` (all if empty), of successful episodes
        only if ``successes_only``."""
        if not sources and not successes_only:
            return self
        names = list(self.header["sources"])
        unknown = sorted(set(sources) - set(names))
        if unknown:
            raise PriorDataError(f"{self.path}: no source {unknown}; it holds {names}")
        keep = torch.ones(len(self), dtype=torch.bool)
        if sources:
            codes = torch.tensor([names.index(s) for s in sources])
            keep &= torch.isin(self.transitions["source"], codes)
        if successes_only:
            keep &= self.transitions["episode_success"]
        if not bool(keep.any()):
            raise PriorDataError(f"{self.path}: no transition of {list(sources) or names}")
        idx = torch.nonzero(keep).squeeze(-1)
        return PriorData(self.transitions[idx], self.header, self.path)

    def as_residual(self, base: nn.Module, chunk: int = 8192) -> PriorData:
        """The transitions with each ``action`` made a residual over the scripted driver
        ``base``: ``clamp(action - base(obs), -1, 1)``, which the residual env
        (:class:`~sharedspace.train.envs.ResidualAction`) turns back into the recorded action
        wherever that lies within 1 of the script's. The script is mirror-symmetric, so the
        mirror augmentation holds for the residual too."""
        actions = []
        with torch.no_grad():
            for start in range(0, len(self), chunk):
                rows = self.transitions[start : start + chunk]
                scripted = base(rows["features"], rows["mask"]).to(rows["action"].dtype)
                actions.append((rows["action"] - scripted).clamp(-1.0, 1.0))
        transitions = self.transitions.copy()  # shallow: the memory map stays as it is
        transitions.set("action", torch.cat(actions) if actions else self.transitions["action"])
        return PriorData(transitions, self.header, self.path)

    def sample(self, batch_size: int, generator: torch.Generator | None = None) -> TensorDict:
        """``batch_size`` transitions drawn uniformly with replacement (:meth:`take`)."""
        return self.take(torch.randint(len(self), (batch_size,), generator=generator), generator)

    def take(self, idx: torch.Tensor, generator: torch.Generator | None = None) -> TensorDict:
        """The transitions ``idx`` (:data:`KEYS`), those of successful episodes first, a random
        half of them mirrored (:func:`mirrored`)."""
        idx = idx[torch.argsort((~self.transitions["episode_success"][idx]).byte(), stable=True)]
        batch = self._data[idx].clone()
        return _flip(batch, torch.rand(len(idx), generator=generator) < 0.5)


def _flip(batch: TensorDict, flip: torch.Tensor) -> TensorDict:
    """``batch`` with the rows of ``flip`` mirrored (in place)."""
    sign = 1.0 - 2.0 * flip.to(torch.float32)  # -1 where mirrored
    for key in ("features", ("next", "features")):
        f = batch.get(key)
        for col in MIRRORED_FEATURES:
            f[..., col] *= sign.view(-1, *([1] * (f.dim() - 2)))
    batch["action"][..., MIRRORED_ACTION] *= sign
    return batch


def mirrored(batch: TensorDictBase) -> TensorDictBase:
    """A copy of ``batch`` (transitions of :data:`KEYS`) reflected about the ego's axis."""
    out = batch.select(*KEYS).clone()
    return _flip(out, torch.ones(out.shape[0], dtype=torch.bool))


def write_prior(
    path: str | Path,
    transitions: TensorDictBase,
    world: dict[str, Any],
    sources: dict[str, dict[str, Any]],
    command: str = "",
) -> dict[str, Any]:
    """Writes a dataset (``transitions`` with :data:`KEYS` and :data:`LABELS`, ``sources``
    in the order their codes count) to the directory ``path``; returns its header."""
    missing = [k for k in (*KEYS, *LABELS) if k not in transitions.keys(include_nested=True)]
    if missing:
        raise PriorDataError(f"transitions lack {missing}")
    out = Path(path)
    out.mkdir(parents=True, exist_ok=True)
    transitions.select(*KEYS, *LABELS).memmap(out / "transitions")
    header = {
        "format": FORMAT,
        "version": VERSION,
        "world": world,
        "transitions": int(transitions.shape[0]),
        "sources": sources,
        "created": time.strftime("%Y-%m-%d %H:%M UTC", time.gmtime()),
        "command": command,
    }
    (out / "header.json").write_text(json.dumps(header, indent=1))
    return header


def read_header(path: str | Path) -> dict[str, Any]:
    """The header of the dataset at ``path``, checked for format and version."""
    file = Path(path) / "header.json"
    if not file.is_file():
        raise PriorDataError(f"{path}: not a prior dataset (no header.json; `make demos`)")
    header = json.loads(file.read_text())
    if header.get("format") != FORMAT or header.get("version") != VERSION:
        raise PriorDataError(
            f"{path}: format {header.get('format')!r} version {header.get('version')!r}; "
            f"this trainer reads {FORMAT!r} version {VERSION}"
        )
    return header


def load_prior(path: str | Path, cfg: TrainConfig) -> PriorData:
    """The dataset at ``path``, memory-mapped, if it was recorded in ``cfg``'s world
    (:func:`world_of`); else :class:`PriorDataError` naming every field that differs."""
    header = read_header(path)
    diff = _differences(header["world"], world_of(cfg.world, cfg.reward_weights))
    if diff:
        raise PriorDataError(
            f"{path} was recorded in another world than this trainer's: " + "; ".join(diff)
        )
    return PriorData(TensorDict.load_memmap(Path(path) / "transitions"), header, str(path))


def make_prior(cfg: TrainConfig) -> PriorData | None:
    """The prior data of ``cfg`` (``prior_data``, its ``prior_sources``, successes only if
    ``prior_successes_only``), or None without. A residual learner (``base_driver``) gets
    the actions as residuals over its script (:meth:`PriorData.as_residual`)."""
    if not cfg.algo.prior_data:
        return None
    sources = [s.strip() for s in cfg.algo.prior_sources.split(",") if s.strip()]
    prior = load_prior(cfg.algo.prior_data, cfg).select(sources, cfg.algo.prior_successes_only)
    return prior.as_residual(SCRIPTED[cfg.algo.base_driver]()) if cfg.algo.base_driver else prior


def mixed_batch(buffer, prior: PriorData | None, cfg: TrainConfig) -> tuple[TensorDict, int]:
    """RLPD's symmetric sampling: a replay batch of ``batch_size`` whose first
    ``round(batch_size * prior_ratio)`` rows come from the prior data, the rest from the
    online ``buffer``; and how many of its first rows are prior transitions of successful
    episodes (the rows a BC term imitates)."""
    if prior is None or cfg.algo.prior_ratio <= 0:
        return buffer.sample(), 0
    online = buffer.sample().select(*KEYS)  # the buffer's batches are the online part
    idx = torch.randint(len(prior), (cfg.algo.batch_size - online.shape[0],))
    succeeded = int(prior.transitions["episode_success"][idx].sum())
    return torch.cat([prior.take(idx), online]), succeeded


def clone(update, prior: PriorData, steps: int, cfg: TrainConfig) -> list[float]:
    """``steps`` behaviour-cloning steps of the actor on batches of the prior data's
    successful episodes (:meth:`~sharedspace.train.update.SACUpdate.clone_step`); the loss
    of each."""
    good = prior.select(successes_only=True)
    return [
        float(update.clone_step(good.sample(cfg.algo.batch_size).to(cfg.device)))
        for _ in range(steps)
    ]
