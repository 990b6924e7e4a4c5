"""The crossing task's definition, with no torch: its scenes, cars and crowd
(:class:`CrossingTask`); :mod:`sharedspace.marl.task` plays it (its envs, observations)."""

from __future__ import annotations

from dataclasses import dataclass, field

from sharedspace.pool import synthetic_names
from sharedspace.wire.requests import EnvSpec, SyntheticScenes
from sharedspace.worlds import TRAINING_TASKS

__all__ = ["CROSSING_CROWD", "VALIDATION_SEED", "CrossingTask"]

#: CR-SFM parameters of Table II-G's world (params/table2g.json5: the calibrated crowd and its
#: risk weights), as per-env overrides.
CROSSING_CROWD: dict[str, float] = {
    "tau": 0.74303,
    "a_ped": 1.0562,
    "b_ped": 0.1,
    "a_veh": 5.0,
    "b_veh": 0.66589,
    "lambda1": 1.3439,
    "lambda2": 0.63559,
    "lambda3": 0.0,
    "gamma1": 0.5,
    "gamma2": 1.0,
}


#: The first validation scene's seed: far from the train (0 ..) and test (1 000 000 ..) seeds.
VALIDATION_SEED = 500_000


@dataclass(frozen=True)
class CrossingTask:
    """The frozen multi-car task; one field per choice, the defaults are the task."""

    cars: int = TRAINING_TASKS["crossing"].cars  # controlled cars per scene (vehicle_0 ..
    #                                               vehicle_{cars-1}), 2-4
    pedestrians: int = 12  # pedestrians per scene
    density: float = 0.06  # pedestrians per m² of the crowd's square (side 14.1 m at 12)
    layout: str = "crossing"  # where the pedestrians walk (SyntheticScenes.layout)
    train_seed: int = 0  # seed of the first training scene
    train_scenes: int = 256  # training scenes (seeds train_seed ..; a request makes at most 256)
    test_seed: int = 1_000_000  # seed of the first test scene
    test_scenes: int = 100  # test scenes: cars x test_scenes car-episodes
    max_agents: int = TRAINING_TASKS["crossing"].max_agents  # M, nodes per observation (the
    #                                                         car and its 9 nearest agents)
    crowd: dict[str, float] = field(default_factory=lambda: dict(CROSSING_CROWD))  # CR-SFM

    def __hash__(self) -> int:  # a dict field: hash the values that define the task
        return hash((self.cars, self.pedestrians, self.density, self.layout, self.test_seed))

    @property
    def agents(self) -> tuple[str, ...]:
        return tuple(f"vehicle_{k}" for k in range(self.cars))

    def scenes(self, split: str, count: int | None = None) -> SyntheticScenes:
        """The generated scenes of ``split``: ``train``, ``test``, or ``validation`` (the first
        ``count`` of the seeds from :data:`VALIDATION_SEED`, between the train and the test
        seeds: never trained on, never tested on)."""
        seed, default = {
            "train": (self.train_seed, self.train_scenes),
            "validation": (VALIDATION_SEED, TRAINING_TASKS["crossing"].validation_scenes),
            "test": (self.test_seed, self.test_scenes),
        }[split]
        count = count or default
        return SyntheticScenes(
            layout=self.layout,
            pedestrians=self.pedestrians,
            density=self.density,
            vehicles=self.cars,
            routes="intersection",
            seed=seed,
            scenes=count,
        )

    def scene_names(self, split: str, count: int | None = None) -> list[str]:
        return [name for name, _ in synthetic_names(self.scenes(split, count), split)]

    def spec(self, split: str, seed: int = 0, count: int | None = None) -> EnvSpec:
        """The envs of ``split`` (its first ``count`` scenes); ``seed`` seeds the server's
        draw of training scenes."""
        return EnvSpec(
            synthetic=self.scenes(split, count),
            external_agents=self.agents,
            max_agents=self.max_agents,
            pedestrian_params=dict(self.crowd),
            seed=seed,
        )
