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

import torch
from tensordict import TensorDictBase
from torch import nn
from torchrl.data import Composite, Unbounded
from torchrl.envs import Transform

from sharedspace.client import Connection, SimClient
from sharedspace.marl.crossing import CROSSING_CROWD, VALIDATION_SEED, CrossingTask
from sharedspace.names import FEATURE_SCALE, NODE_FEATURES
from sharedspace.torchrl_multiagent import RemoteMultiAgentEnv

__all__ = [
    "CROSSING_CROWD",
    "VALIDATION_SEED",
    "CarObservation",
    "CrossingTask",
    "FlatObservation",
    "make_env",
]


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
