"""The crossing task: several cars through one intersection among a crowd (issue 41).

Four cars head +x, +y, -x and -y through a four-way crossing at the centre of a square of
pedestrians who walk across the square (``CreateEnv.synthetic``, routes ``intersection``: every
car is there from step 0, the others 0-2 s of driving behind the first's start line, drawn from
the scene's seed). Each car is a learner (``vehicle_0 .. vehicle_3``); the crowd follows CR-SFM
with the parameters of Table II-G's world (``params/table2g.json5``), sent with the env
request, so that any server plays the same task. Scenes are seeded: training draws from the
``train_scenes`` scenes from ``train_seed``, the test set is the ``test_scenes`` scenes from
``test_seed``, far apart, and never trained on.

With every car running the car-aware script a car reaches its goal in about 0.70 of the test
episodes; docs/RESULTS.md ("Several cars per scene") has the figures and the planner's bound.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import torch
from tensordict import TensorDictBase
from torch import nn
from torchrl.data import Composite, Unbounded
from torchrl.envs import Transform

from sharedspace.client import Connection, SimClient
from sharedspace.names import FEATURE_SCALE, NODE_FEATURES
from sharedspace.torchrl_env import synthetic_names
from sharedspace.torchrl_multiagent import RemoteMultiAgentEnv
from sharedspace.wire.requests import EnvSpec, SyntheticScenes

__all__ = [
    "CROSSING_CROWD",
    "CarObservation",
    "CrossingTask",
    "FlatObservation",
    "make_env",
]

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

    cars: int = 4  # controlled cars per scene (vehicle_0 .. vehicle_{cars-1}), 2-4
    pedestrians: int = 12  # pedestrians per scene
    density: float = 0.06  # pedestrians per m² of the crowd's square (side 14.1 m at 12)
    layout: str = "crossing"  # where the pedestrians walk (SyntheticScenes.layout)
    train_seed: int = 0  # seed of the first training scene
    train_scenes: int = 256  # training scenes (seeds train_seed ..; a request makes at most 256)
    test_seed: int = 1_000_000  # seed of the first test scene
    test_scenes: int = 100  # test scenes: cars x test_scenes car-episodes
    max_agents: int = 10  # M, nodes per observation (the car and its 9 nearest agents)
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
            "validation": (VALIDATION_SEED, 50),
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


def make_env(
    task: CrossingTask,
    split: str,
    num_envs: int,
    client: SimClient | Connection,
    *,
    seed: int = 0,
    scenarios: list[str] | None = None,
    reward_weights: dict[str, float] | None = None,
) -> RemoteMultiAgentEnv:
    """``num_envs`` server envs of the task in TorchRL's multi-agent layout (group
    ``vehicle``); ``scenarios`` pins sub-env ``k`` to ``scenarios[k]`` (an evaluation);
    ``reward_weights`` overrides the world's (SPEC 8.2: a learner's shaping, not the task's
    measure, which is per-car success)."""
    count = len(scenarios) if split == "validation" and scenarios else None
    spec = task.spec(split, seed, count)
    if reward_weights:
        spec = spec.replace(reward_weights=dict(reward_weights))
    return RemoteMultiAgentEnv(spec, num_envs, client=client, scenarios=scenarios)


class CarObservation(nn.Module):
    """Each car's observation as one vector: its ``M`` nodes' features (scaled to O(1),
    padding zeroed) and the mask, flattened: ``[*, A, M, F]`` -> ``[*, A, M * (F + 1)]``."""

    def __init__(self):
        super().__init__()
        self.register_buffer("scale", torch.tensor(FEATURE_SCALE[:NODE_FEATURES]))

    def forward(self, features: torch.Tensor, mask: torch.Tensor) -> torch.Tensor:
        m = mask.to(features.dtype).unsqueeze(-1)
        return torch.cat([features / self.scale * m, m], -1).flatten(-2)


class FlatObservation(Transform):
    """Adds ``(group, "observation")``, :class:`CarObservation` of the group's features and
    mask, to the env's outputs and specs: the one vector per car that generic multi-agent
    models (BenchMARL's) read."""

    def __init__(self, group: str = "vehicle"):
        keys = [(group, "features"), (group, "mask")]
        super().__init__(in_keys=keys, out_keys=[(group, "observation")])
        self.group = group
        self.encode = CarObservation()

    def _call(self, tensordict: TensorDictBase) -> TensorDictBase:
        features, mask = (tensordict.get(k) for k in self.in_keys)
        tensordict.set(self.out_keys[0], self.encode(features, mask))
        return tensordict

    def _reset(self, tensordict: TensorDictBase, tensordict_reset: TensorDictBase):
        return self._call(tensordict_reset)

    def transform_observation_spec(self, observation_spec: Composite) -> Composite:
        group = observation_spec[self.group]
        m, f = group["features"].shape[-2:]
        shape = (*group.shape, m * (f + 1))
        group["observation"] = Unbounded(shape, dtype=torch.float32, device=group.device)
        return observation_spec
