"""What a world is, as a config: the pool and its world parameters, ``max_agents``, the crowd and
the cars, the training variations and composed scenes, the validation split, and the server
that serves it. Torch-free: a trainer's run config holds one
(:class:`sharedspace.train.config.TrainConfig`), and the paper's tools, the bench and the
adversary describe their worlds with it alone.

``task=paper`` (or ``crowd``, ``crossing``) fills in the task's training world
(:data:`sharedspace.worlds.TRAINING_TASKS`): a field left at its default takes the task's
value; a world field given another value is refused by name (the training variations and the
validation split's size may differ: neither changes the task's test side). Building one writes
no file and asks no server; it reads the pool file once per process (the validation split's
names) to check the split.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

from sharedspace.cli import UserError, declared_default, did_you_mean, parse_value
from sharedspace.client import Connection
from sharedspace.models import DEFAULT_MODEL
from sharedspace.pool import load_pool, split_indices
from sharedspace.wire import ComposedScenes, EnvSpec
from sharedspace.worlds import (
    TRAINING_TASKS,
    UnknownTask,
    held_out_scenes,
    training_task,
    world_params_file,
)

__all__ = ["TRAINING_CHOICES", "WorldConfig", "WorldConfigError", "task_fields"]


class WorldConfigError(UserError):
    """A world field with a wrong value, or one that contradicts the task; the message names
    the field."""


#: World fields a task sets by default that a run may set otherwise: how it trains and
#: validates, not the world its policy is scored in.
TRAINING_CHOICES = ("variations", "validation_scenes", "validation_variations")


@dataclass
class WorldConfig:
    """A world and where it is served. One line of doc per field."""

    # --- world
    task: str = ""  # train for a benchmark task: paper | crowd (one car) | crossing (several)
    scenario_pool: str = ""  # scenario file path; "" = scenarios/data/hbs-paper.json
    server_params: str = ""  # world-parameter file of a local server; "" = its defaults
    max_agents: int = 8  # M, graph nodes per observation (ego + M-1 nearest agents)
    pedestrian_model: str = DEFAULT_MODEL  # model of the simulated crowd (sharedspace.models)
    vehicle_model: str = ""  # cars nobody controls: replay | idm (reactive); "" = the pool's
    variations: dict[str, Any] = field(
        default_factory=dict
    )  # scene variations of the training envs (SPEC 5.2.1; JSON on --set); {} = none
    scenes: int = 0  # composed scenes the training envs draw beside the recorded train scenes
    #                  (SPEC 5.2.2, from their recorded parts, never a validation or test
    #                  scene's); 0 = none; -1 = a fresh one every episode, no recorded ones
    scenes_seed: int = 0  # the composed scenes' generator seed (the same scenes for every seed)
    # --- validation
    eval_split: str = "validation"  # validation (carved from the train scenes) | test
    validation_scenes: int = TRAINING_TASKS["paper"].validation_scenes  # train scenes carved
    #                                                                     off as the validation
    #                                                                     split
    validation_variations: int = 8  # seeded variations of each validation scene per scoring
    # --- server
    server_endpoint: str = ""  # Zenoh endpoint of the server; "" = a local sim-server the run
    #                            starts, serving the run's pools and world
    server_prefix: str = "sharedspace"  # Zenoh key prefix of the server
    zenoh_config: str = ""  # trainer session file (deploy/trainer.json5); "" = peer on endpoint
    failover: bool = True  # a lost server's envs are re-created on a survivor (its episodes end
    #                        truncated); with one server the run ends as without

    def __post_init__(self):
        if self.task:
            self._take_task()
        if self.eval_split not in ("validation", "test"):
            raise WorldConfigError(
                f"eval_split must be validation or test, not {self.eval_split!r}"
            )
        if self.scenes < -1 or self.scenes_seed < 0:
            raise WorldConfigError(
                f"scenes must be -1 (a fresh one every episode), 0 (none) or a count, not "
                f"{self.scenes}; scenes_seed at least 0, not {self.scenes_seed}"
            )
        for name in ("max_agents", "validation_scenes", "validation_variations"):
            if getattr(self, name) < 1:
                raise WorldConfigError(f"{name} must be at least 1, not {getattr(self, name)}")
        try:
            self.env_spec("train", 0, self.variations)  # a wrong env field named now
        except ValueError as err:
            raise WorldConfigError(str(err)) from None

    def _take_task(self) -> None:
        values = task_fields(self.task)
        for name, value in values.items():
            given = getattr(self, name)
            if given == declared_default(WorldConfig, name):
                setattr(self, name, value)
            elif given != value and name not in TRAINING_CHOICES:  # the world's
                raise WorldConfigError(
                    f"{name} is set by task={self.task} ({value!r}); this config gives {given!r}"
                )

    @classmethod
    def from_words(cls, words: Sequence[str]) -> WorldConfig:
        """A world from ``key=value`` words (a tool's ``--set``), each value parsed like the
        field's default; a key that is no world field is refused by name."""
        given: dict[str, Any] = {}
        for word in words:
            key, eq, text = word.partition("=")
            key = key.strip()
            if not eq:
                raise WorldConfigError(f"--set {word!r}: expected KEY=VALUE")
            if key not in cls.__dataclass_fields__:
                raise WorldConfigError(
                    f"{key!r} is no key of the world{did_you_mean(key, cls.__dataclass_fields__)}"
                    f"; the world's keys: {', '.join(cls.__dataclass_fields__)}"
                )
            given[key] = parse_value(
                key, text, declared_default(WorldConfig, key), WorldConfigError
            )
        return cls(**given)

    @property
    def cars(self) -> int:
        """Learning cars per scene: the task's (several in ``crossing``), else one."""
        return training_task(self.task).cars if self.task else 1

    def record(self) -> dict[str, Any]:
        """What a checkpoint records of this world: the task (if any), pool (the validation
        pool carved from it too), world parameters, M, crowd, cars and variations."""
        keys = ("task", "scenario_pool", "server_params", "max_agents", "pedestrian_model")
        out: dict[str, Any] = {k: getattr(self, k) for k in keys}
        out |= {"vehicle_model": self.vehicle_model, "variations": dict(self.variations)}
        if self.scenes:
            out["composed"] = {"scenes": self.scenes, "seed": self.scenes_seed}
        if self.eval_split == "validation":
            out["validation"] = {"scenes": self.validation_scenes, "seed": 0}
        return out

    def validation_names(self) -> tuple[str, ...]:
        """The train scenes of ``scenario_pool`` carved off as the validation split, in pool
        order (:func:`sharedspace.worlds.validation_pool`: ``random.Random(0).sample``); none
        with ``eval_split=test``. The training envs never draw them (``CreateEnv.exclude``), so
        any server of the pool serves every trainer's carve. Reads the pool file once per
        process and writes nothing."""
        if self.eval_split != "validation":
            return ()
        return held_out_scenes(self.scenario_pool, self.validation_scenes)[1]

    def pool_scenes(self) -> list[dict[str, Any]]:
        """``scenario_pool``'s scenes in pool order: what an env's ``scenario_index`` indexes."""
        return load_pool(self.scenario_pool or None)

    def scene_indices(self, split: str) -> list[int]:
        """Indices into :meth:`pool_scenes` of the recorded scenes an env of ``split`` plays:
        the train scenes less the validation split (``train``), the validation split, or the
        test scenes."""
        pool = self.pool_scenes()
        if split == "test":
            return split_indices(pool, "test")
        held = set(self.validation_names())
        keep = split == "validation"
        return [i for i in split_indices(pool, "train") if (pool[i]["name"] in held) == keep]

    def env_spec(
        self,
        split: str,
        seed: int,
        variations: dict[str, Any] | None = None,
        reward_weights: dict[str, float] | None = None,
    ) -> EnvSpec:
        """The envs of this world: ``split`` (``train`` draws the pool's train scenes less the
        validation split; ``validation`` envs play the validation scenes by name,
        :func:`sharedspace.train.envs.make_env`), ``seed``, scene ``variations`` and the
        reward's ``reward_weights`` over the world's. Writes nothing."""
        return EnvSpec(
            # the default by its name (hbs-paper, never "the server's first pool"); a file by
            # its path, which the envs read
            pool=self.scenario_pool or held_out_scenes("", 0)[0],
            split="test" if split == "test" else "train",
            seed=seed,
            pedestrian_model=self.pedestrian_model,
            max_agents=self.max_agents,
            variations=variations or None,
            vehicle_model=self.vehicle_model or None,
            reward_weights=dict(reward_weights or {}),
            exclude=self.validation_names() if split == "train" else (),
            composed=self.composed_scenes() if split == "train" else None,
        )

    def composed_scenes(self) -> ComposedScenes | None:
        """The training envs' composed scenes (``scenes``): made from the train scenes of
        ``scenario_pool`` less the validation split (its test scenes never enter either);
        None for ``scenes=0``. Reads the pool file (the scenes' names) and writes nothing."""
        if self.scenes == 0:
            return None
        held = self.validation_scenes if self.eval_split == "validation" else 0
        source, hold_out = held_out_scenes(self.scenario_pool, held)
        return ComposedScenes(
            scenes=None if self.scenes < 0 else self.scenes,
            seed=self.scenes_seed,
            source=source,
            hold_out=hold_out,
        )

    def connection(self) -> Connection:
        """Where the envs live (:meth:`sharedspace.client.Connection.resolve`): the zenoh file,
        else the endpoint, else a local ``sim-server`` of this world's pool (the server's
        embedded pools for the default) and parameters; with ``failover``."""
        params = self.server_params or None
        if params and self.task and params == training_task(self.task).server_params:
            params = str(world_params_file(training_task(self.task)))  # found outside a checkout
        conn = Connection.resolve(
            self.server_endpoint,
            self.server_prefix,
            self.zenoh_config,
            [self.scenario_pool] if self.scenario_pool else [],
            params,
        )
        return conn.replace(failover=self.failover) if self.failover else conn


def task_fields(name: str) -> dict[str, Any]:
    """The world fields ``task=name`` fills in, with the task's values."""
    try:
        task = training_task(name)
    except UnknownTask as err:
        raise WorldConfigError(str(err)) from None
    return {
        "scenario_pool": task.pool,
        "server_params": task.server_params,
        "max_agents": task.max_agents,
        "variations": dict(task.variations),
        "validation_scenes": task.validation_scenes,
        "validation_variations": task.validation_variations,
    }
