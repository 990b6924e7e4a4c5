"""Scenario pools (scenarios/FORMAT.md) as the Python side reads them: the scenarios of a file,
the indices of a split, and what a record says without simulating anything (an agent's heading
at every sample)."""

from __future__ import annotations

import json
import math
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

if TYPE_CHECKING:
    from sharedspace.wire.requests import SyntheticScenes

__all__ = [
    "synthetic_names",
    "DEFAULT_POOL_PATH",
    "listed_scenarios",
    "load_pool",
    "recorded_headings",
    "split_indices",
]

#: The paper's scenario pool (HBS shared space, 59 train + 18 test scenarios): the checkout's
#: file, or in an installed wheel the copy it carries (``make wheel``).
DEFAULT_POOL_PATH = Path(__file__).resolve().parents[3] / "scenarios" / "data" / "hbs-paper.json"
if not DEFAULT_POOL_PATH.is_file():
    DEFAULT_POOL_PATH = Path(__file__).resolve().parent / "pool_data" / "hbs-paper.json"


def load_pool(path: str | Path | None = None) -> list[dict[str, Any]]:
    """The scenarios of a scenario file (scenarios/FORMAT.md), in pool order."""
    return json.loads(Path(path or DEFAULT_POOL_PATH).read_text())["scenarios"]


def listed_scenarios(pool: Any) -> tuple[str | None, list[tuple[str, str]] | None]:
    """``(pool name, [(scenario name, split), ...])`` in pool order of a pool the caller holds: a
    pool file's path, a pool document or a list of scenario dicts. For a pool name, or None (the
    server's default pool), ``(pool, None)``: the server serving it lists its scenarios
    (:meth:`~sharedspace.client.SimClient.scenarios`), which is what every env asks then."""
    if pool is None:
        return None, None
    if isinstance(pool, str | Path):
        if not (str(pool).endswith(".json") or Path(pool).is_file()):
            return str(pool), None
        pool = json.loads(Path(pool).read_text())
    if isinstance(pool, Mapping):
        name, scenarios = pool.get("name"), pool["scenarios"]
    else:
        name, scenarios = None, list(pool)
    return name, [(str(s["name"]), str(s.get("split", "train"))) for s in scenarios]


def split_indices(pool: Sequence[Mapping[str, Any]], split: str | None) -> list[int]:
    """Pool indices of the scenarios of ``split`` (``"train"``, ``"test"``, or ``None``/"all")."""
    if split in (None, "all"):
        return list(range(len(pool)))
    if split not in ("train", "test"):
        raise ValueError(f"unknown split {split!r}")
    out = [i for i, s in enumerate(pool) if s.get("split") == split]
    if not out:
        raise ValueError(f"no scenario in split {split!r}")
    return out


def recorded_headings(velocities: np.ndarray) -> np.ndarray:
    """Heading at every sample of a record (as sim-core's ``recorded_heading``): the direction of
    the recorded velocity, or of the nearest moving sample (earlier first on ties), 0 if it
    never moves."""
    n = len(velocities)
    speeds = np.hypot(velocities[:, 0], velocities[:, 1])
    moving = speeds > 1e-6
    out = np.zeros(n)
    for k in range(n):
        for d in range(n):
            found = None
            for idx in (k - d, k + d):
                if 0 <= idx < n and moving[idx]:
                    found = idx
                    break
            if found is not None:
                out[k] = math.atan2(velocities[found, 1], velocities[found, 0])
                break
    return out


def synthetic_names(synthetic: SyntheticScenes, split: str) -> list[tuple[str, str]]:
    """The scenes a ``CreateEnv.synthetic`` request makes, as ``(name, split)`` in order (the
    server names them ``synthetic-{layout}-n{N}[-v{V}[-intersection]]-seed{seed}``, SPEC 5.2)."""
    s = synthetic
    vehicles = f"-v{s.vehicles}" if s.vehicles > 1 or s.routes == "intersection" else ""
    vehicles += "-intersection" if s.routes == "intersection" else ""
    return [
        (f"synthetic-{s.layout}-n{s.pedestrians}{vehicles}-seed{s.seed + i}", split)
        for i in range(s.scenes)
    ]
