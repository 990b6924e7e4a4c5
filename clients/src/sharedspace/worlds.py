"""The worlds of the benchmark's tasks, what training *for a task* takes from them, and the
validation split carved from a pool's train scenes.

``--set task=paper`` (or ``crowd``) sets the training world of the benchmark's task of that name
(:mod:`sharedspace.bench.tasks` holds the frozen test side and checks that it agrees with this
table): the pool whose train split is trained on, the world parameters, ``max_agents`` and the
training variations. A checkpoint trained so records the task, and ``python -m sharedspace.bench
TASK --policy CKPT`` scores it with no other flag.

**Validation.** Nothing is chosen on test scenes. :func:`validation_pool` carves
``validation_scenes`` of a pool's train scenes (drawn by a fixed seed) off as the validation
split, and :func:`held_out_scenes` names them: a trainer's envs draw the other train scenes
(``CreateEnv.exclude``) and its validation envs play those by name, so a run never sees the
task's test scenes, and any server of the pool serves every trainer's carve. The trainer's
curves (``eval/*``) are drawn on it by default.
"""

from __future__ import annotations

import functools
import hashlib
import json
import random
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from sharedspace.cli import UserError, did_you_mean
from sharedspace.pool import DEFAULT_POOL_PATH

__all__ = [
    "REPO",
    "TABLE2G_WORLD",
    "TABLE2_WORLD",
    "TRAINING_TASKS",
    "TRAINING_VARIATIONS",
    "TrainingTask",
    "UnknownTask",
    "held_out_scenes",
    "training_task",
    "validation_pool",
    "validation_label",
    "world_params_file",
]

#: The repository's root (pool and parameter files are named relative to it).
REPO = Path(__file__).resolve().parents[3]

#: Table II's world (params/table2.json5): the calibrated CR-SFM crowd and its risk weights.
TABLE2_WORLD: dict[str, Any] = {
    "pedestrians": {
        "cr_sfm": {
            "tau": 0.74303,
            "a_ped": 1.0562,
            "b_ped": 0.1,
            "a_veh": 0.1,
            "b_veh": 0.66589,
            "lambda3": 0.0,
            "lambda1": 1.3439,
            "lambda2": 0.63559,
        }
    },
    "risk": {"gamma1": 0.5, "gamma2": 1.0, "lambda": 1.0},
}

#: Table II-G's world (params/table2g.json5): Table II's, pedestrians' vehicle repulsion 5.0.
TABLE2G_WORLD: dict[str, Any] = {
    "pedestrians": {"cr_sfm": {**TABLE2_WORLD["pedestrians"]["cr_sfm"], "a_veh": 5.0}},
    "risk": dict(TABLE2_WORLD["risk"]),
}

#: The scene variations the single-car learners train on (SPEC 5.2.1): wider than the
#: benchmark's, so that a policy meets more than the recorded scenes.
TRAINING_VARIATIONS = {
    "position_sigma": 0.5,
    "start_offset_steps": 2,
    "desired_speed_scale": 0.2,
    "mirror": True,
}


class UnknownTask(UserError):
    """A task name with no training world."""


@dataclass(frozen=True)
class TrainingTask:
    """A task's training world."""

    name: str  # the benchmark task's name
    pool: str  # scenario pool file, relative to the repository ("" = hbs-paper, embedded)
    server_params: str  # world parameters file, relative to the repository
    world_params: dict[str, Any]  # that file's content
    max_agents: int  # M
    variations: dict[str, Any] = field(default_factory=lambda: dict(TRAINING_VARIATIONS))
    validation_scenes: int = 12  # train scenes carved off as the validation split
    validation_variations: int = 8  # seeded variations of each validation scene per scoring
    cars: int = 1  # learning cars per scene (several: python -m sharedspace.marl)


#: Every task's training world by name.
TRAINING_TASKS: dict[str, TrainingTask] = {
    "paper": TrainingTask("paper", "", "params/table2.json5", TABLE2_WORLD, 8),
    "crowd": TrainingTask(
        "crowd",
        "out/table2g/pool-general.json",
        "params/table2g.json5",
        TABLE2G_WORLD,
        10,
        validation_scenes=60,
        validation_variations=4,
    ),
    # generated scenes (sharedspace.marl.crossing.CrossingTask, whose cars, M and validation
    # size are these): its validation scenes are drawn from seeds of their own, apart from the
    # train and the test scenes
    "crossing": TrainingTask(
        "crossing", "", "", {}, 10, variations={}, validation_scenes=50, cars=4
    ),
}


def training_task(name: str) -> TrainingTask:
    """The training world of task ``name``."""
    if name not in TRAINING_TASKS:
        raise UnknownTask(
            f"task must be one of {', '.join(TRAINING_TASKS)}; not {name!r}"
            + did_you_mean(name, TRAINING_TASKS)
        )
    return TRAINING_TASKS[name]


def repo_path(path: str) -> Path:
    """``path`` as given if absolute or present from here, else relative to the repository."""
    p = Path(path)
    return p if p.is_absolute() or p.exists() else REPO / p


def _cache_dir(kind: str) -> Path:
    """``REPO/out/KIND`` in a checkout, else ``~/.cache/sharedspace/KIND``."""
    if (REPO / "clients").is_dir():
        return REPO / "out" / kind
    return Path.home() / ".cache" / "sharedspace" / kind


def world_params_file(task: TrainingTask) -> Path:
    """The file of ``task``'s world parameters for a local server: the repository's
    (``task.server_params``) in a checkout, else :attr:`TrainingTask.world_params` written once
    as JSON (which JSON5 reads) under ``~/.cache/sharedspace/params``, named by its content."""
    shipped = repo_path(task.server_params)
    if shipped.is_file():
        return shipped.resolve()
    text = json.dumps(task.world_params, sort_keys=True, indent=1)
    digest = hashlib.sha256(text.encode()).hexdigest()[:12]
    path = _cache_dir("params") / f"{Path(task.server_params).stem}-{digest}.json"
    if not path.is_file():
        path.parent.mkdir(parents=True, exist_ok=True)
        tmp = path.with_suffix(".tmp")
        tmp.write_text(text)
        tmp.replace(path)
    return path


def validation_pool(pool: dict[str, Any], n: int, seed: int = 0) -> dict[str, Any]:
    """A pool document: ``pool``'s train scenes, of which ``n`` (chosen by ``seed``, kept in
    pool order) are in the ``test`` split as validation scenes; ``pool``'s test scenes are left
    out. It keeps ``pool``'s vehicle model and is named ``<name>-validation-<n>-s<seed>``."""
    train = [s for s in pool["scenarios"] if s.get("split", "train") == "train"]
    if not 0 < n < len(train):
        raise ValueError(f"validation_scenes: between 1 and {len(train) - 1} scenes, not {n}")
    held = {s["name"] for s in random.Random(seed).sample(train, n)}
    scenes = [{**s, "split": "test" if s["name"] in held else "train"} for s in train]
    kept = {k: pool[k] for k in ("vehicle_model",) if k in pool}  # the world's cars react alike
    return {
        **kept,
        "version": pool["version"],
        "name": f"{pool['name']}-validation-{n}-s{seed}",
        "provenance": (
            f"{pool['name']}'s {len(train)} train scenes, {n} of them (random.Random({seed})"
            ".sample) as the validation split `test`; its test scenes left out "
            "(sharedspace.worlds.validation_pool)"
        ),
        "scenarios": scenes,
    }


def held_out_scenes(pool: str, n: int, seed: int = 0) -> tuple[str, tuple[str, ...]]:
    """The name of the pool file ``pool`` ("" = hbs-paper) and the names of the ``n`` train
    scenes :func:`validation_pool` carves from it as validation scenes (none for ``n = 0``):
    what a composed scene is never made of (``CreateEnv.composed.hold_out``). Reads the file
    once per process and writes nothing."""
    return _held_out_scenes(str(_pool_source(pool)), n, seed)


@functools.lru_cache(maxsize=8)
def _held_out_scenes(source: str, n: int, seed: int) -> tuple[str, tuple[str, ...]]:
    doc = json.loads(Path(source).read_bytes())
    if n == 0:
        return doc["name"], ()
    held = {s["name"] for s in validation_pool(doc, n, seed)["scenarios"] if s["split"] == "test"}
    return doc["name"], tuple(s["name"] for s in doc["scenarios"] if s["name"] in held)


def validation_label(pool: str, n: int, seed: int = 0) -> str:
    """A name for the carve of ``n`` validation scenes of the pool file ``pool`` ("" =
    hbs-paper) with ``seed``, by the source's content, so that a changed pool gets a new one
    (what a result records of the validation split it was scored on)."""
    source = _pool_source(pool)
    digest = hashlib.sha256(source.read_bytes()).hexdigest()[:12]
    return f"{source.stem}-{digest}-validation-{n}-s{seed}"


def _pool_source(pool: str) -> Path:
    source = repo_path(pool) if pool else DEFAULT_POOL_PATH
    if not source.is_file():
        raise FileNotFoundError(
            f"the pool file {source} is missing (a run's envs, validation split and composed "
            "scenes are read from it)"
        )
    return source
