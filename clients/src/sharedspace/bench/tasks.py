"""The named, frozen tasks a result is reported on.

A task fixes everything that decides its score: the scenes (a pool's test split, checked by a
fingerprint of their content, or the crossing task's generated scenes), the world parameters,
``max_agents``, the pedestrian model, the variations played (spec and seeds) and the number of
cars. Changing any of them makes a new version: a result names ``name@version`` and the
fingerprint, and a comparison between results of different versions is refused.

- ``paper``: the paper's 18 test scenes (``hbs-paper``), each in the 128 seeded variations of
  the powered test, in Table II's world (``params/table2.json5``), ``max_agents`` 8;
- ``crowd``: Table II-G, the 76 test scenes of ``hbs-general`` among reacting cars, each in 4
  seeded variations (304 episodes), its world (``params/table2g.json5``), ``max_agents`` 10;
- ``crossing``: four learning cars through one intersection among 12 pedestrians, the 100 test
  scenes of :class:`sharedspace.marl.task.CrossingTask` (400 car-episodes).
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from sharedspace.cli import UserError, did_you_mean
from sharedspace.marl.crossing import CrossingTask
from sharedspace.outcomes import BENCHMARK_VARIATIONS
from sharedspace.pool import DEFAULT_POOL_PATH
from sharedspace.worlds import REPO, TABLE2_WORLD, TABLE2G_WORLD

__all__ = [
    "TASKS",
    "BenchError",
    "Task",
    "get_task",
    "scenes_fingerprint",
    "test_scenes",
    "versioned",
]


class BenchError(UserError):
    """Input the benchmark refuses before any episode is played: an unknown task, a policy it
    cannot play, a checkpoint of another world, a reference of another task version."""


@dataclass(frozen=True)
class Task:
    """One frozen task; every field decides its score."""

    name: str  # what a result names
    version: int  # bumped whenever any other field changes
    description: str  # one line
    world_params: dict[str, Any]  # the server's world parameters (a params file's content)
    max_agents: int  # M, nodes per observation
    pedestrian_model: str = "cr_sfm"  # the crowd's model
    pool: str = ""  # scenario pool file, relative to the repository (single-car tasks)
    pool_hint: str = ""  # how to make the pool file where it is missing
    test_scenes: int = 0  # scenes of the pool's test split
    scenes_sha256: str = ""  # fingerprint of those scenes (:func:`scenes_fingerprint`)
    variations: int = 0  # seeded variations per scene, seeds 0 .. variations - 1 (0: as recorded)
    variation_spec: dict[str, Any] = field(default_factory=dict)  # SPEC 5.2.1
    crossing: CrossingTask | None = None  # the multi-car task's generated scenes and cars
    scenes_fixed_interval: bool = False  # also report the interval with the scenes held fixed

    def __hash__(self) -> int:
        return hash((self.name, self.version))

    @property
    def cars(self) -> int:
        """Controlled cars per scene."""
        return self.crossing.cars if self.crossing is not None else 1

    @property
    def episodes(self) -> int:
        """Episodes of one play of the task (car-episodes for several cars)."""
        if self.crossing is not None:
            return self.crossing.test_scenes * self.crossing.cars
        return self.test_scenes * max(self.variations, 1)

    @property
    def tag(self) -> str:
        return f"{self.name}@{self.version}"

    def pool_path(self) -> Path:
        """The pool file; a :class:`BenchError` saying how to make it where it is missing."""
        path = Path(self.pool) if Path(self.pool).is_absolute() else REPO / self.pool
        if not path.is_file():
            raise BenchError(
                f"task {self.tag}: its scenes are in {self.pool}, missing: {self.pool_hint}"
            )
        return path

    def fingerprint(self) -> str:
        """What a result records of the task: the scenes' fingerprint and every other field."""
        fields = {f.name: getattr(self, f.name) for f in dataclasses.fields(self)}
        fields["crossing"] = dataclasses.asdict(self.crossing) if self.crossing else None
        fields.pop("description")
        fields.pop("pool_hint")
        blob = json.dumps(fields, sort_keys=True, separators=(",", ":")).encode()
        return hashlib.sha256(blob).hexdigest()[:16]

    def check_scenes(self) -> list[dict[str, Any]]:
        """The task's test scenes from its pool file, after checking they are the frozen ones."""
        scenes = test_scenes(self.pool_path())
        found = scenes_fingerprint(scenes)
        if found != self.scenes_sha256 or len(scenes) != self.test_scenes:
            raise BenchError(
                f"task {self.tag}: {self.pool} holds {len(scenes)} test scenes of fingerprint "
                f"{found[:16]}, not the task's {self.test_scenes} ({self.scenes_sha256[:16]}): "
                "the pool changed, so the task needs a new version"
            )
        return scenes


def test_scenes(pool_file: Path) -> list[dict[str, Any]]:
    """The scenes of a pool file's test split, in pool order."""
    pool = json.loads(Path(pool_file).read_text())
    return [s for s in pool["scenarios"] if s.get("split", "train") == "test"]


def scenes_fingerprint(scenes: list[dict[str, Any]]) -> str:
    """sha256 of the scenes' canonical JSON (sorted keys, no spaces)."""
    blob = json.dumps(scenes, sort_keys=True, separators=(",", ":")).encode()
    return hashlib.sha256(blob).hexdigest()


_PAPER_POOL = (
    str(DEFAULT_POOL_PATH.relative_to(REPO))
    if DEFAULT_POOL_PATH.is_relative_to(REPO)
    else str(DEFAULT_POOL_PATH)
)

#: Every task by name.
TASKS: dict[str, Task] = {
    "paper": Task(
        name="paper",
        version=1,
        description="the paper's 18 test scenes x 128 seeded variations (the powered test), "
        "Table II's world",
        world_params=TABLE2_WORLD,
        max_agents=8,
        pool=_PAPER_POOL,
        pool_hint="it ships with the repository (scenarios/data/hbs-paper.json)",
        test_scenes=18,
        scenes_sha256="7d56be85638381ec38722ed1e0fb7909b22001dc091307a923a141d7f62d1016",
        variations=128,
        variation_spec=BENCHMARK_VARIATIONS,
        scenes_fixed_interval=True,
    ),
    "crowd": Task(
        name="crowd",
        version=1,
        description="Table II-G: hbs-general's 76 test scenes x 4 seeded variations among "
        "reacting cars, its world",
        world_params=TABLE2G_WORLD,
        max_agents=10,
        pool="out/table2g/pool-general.json",
        pool_hint="`make out/table2g/pool-general.json` extracts it from scenarios/data/hbs.csv.gz",
        test_scenes=76,
        scenes_sha256="772fcefb55bbaf5cb150fd6a9703a62e8613755bce3c3add05465ea8b5f80840",
        variations=4,
        variation_spec=BENCHMARK_VARIATIONS,
    ),
    "crossing": Task(
        name="crossing",
        version=1,
        description="4 cars through one intersection among 12 pedestrians, 100 test scenes",
        world_params={},
        max_agents=CrossingTask().max_agents,
        crossing=CrossingTask(),
    ),
}


def get_task(name: str | Task) -> Task:
    """The task of that name (``paper``, ``crowd``, ``crossing``; ``name@version`` checks the
    version too)."""
    if isinstance(name, Task):
        return name
    return versioned(str(name), TASKS, BenchError)


def versioned(name: str, registry: dict[str, Any], error: type[Exception] = BenchError) -> Any:
    """The entry ``name`` of a registry of frozen tasks, ``name@version`` checking the
    version too; ``error`` naming the known ones or the version there is."""
    base, _, version = name.partition("@")
    if base not in registry:
        close = did_you_mean(base, registry)
        raise error(f"unknown task {name!r}: one of {', '.join(registry)}{close}")
    task = registry[base]
    if version and version != str(task.version):
        raise error(f"task {base} is at version {task.version}, not {version}")
    return task
