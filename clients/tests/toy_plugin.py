"""A learner's plug-in from outside the package, as a user writes one: a toy network and a toy
algorithm, each registered once by importing this module. Nothing in ``sharedspace`` names
them (clients/tests/test_learners.py trains and scores them; test_learner_protocol.py holds
them to the loop's contract).

- ``toy_mean``: the masked mean of each observation's scaled node features, then one layer;
- ``toy_pg``: a policy gradient (REINFORCE with the batch's mean reward as baseline) on the
  tanh-normal actor over any registered network, for one car per env or the crossing task's
  cars (``cars="any"``), a learner of the one training loop.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import torch
from torch import nn

from sharedspace.marl.networks import GROUP
from sharedspace.marl.networks import make_actor as make_car_actor
from sharedspace.marl.train import Cars
from sharedspace.names import FEATURE_SCALE, NODE_FEATURES
from sharedspace.train.algorithm_configs import AlgorithmConfig
from sharedspace.train.loop import OneCar
from sharedspace.train.networks import Network, register_network
from sharedspace.train.policy import make_encoder, make_gaussian_actor
from sharedspace.train.registry import Algorithm, register_algorithm


class MeanEncoder(nn.Module):
    """``[*, M, F]`` -> ``[*, 16]``: the present nodes' mean scaled features, one ReLU layer."""

    out_features = 16

    def __init__(self):
        super().__init__()
        self.register_buffer("scale", torch.tensor(FEATURE_SCALE[:NODE_FEATURES]))
        self.layer = nn.Linear(NODE_FEATURES, self.out_features)

    def forward(self, features, adjacency, mask):
        m = mask.to(features.dtype).unsqueeze(-1)
        mean = (features / self.scale * m).sum(-2) / m.sum(-2).clamp_min(1.0)
        return torch.relu(self.layer(mean))


register_network(Network("toy_mean", "ToyMean", lambda cfg, norm: MeanEncoder()))


def make_actor(cfg, action_spec):
    """The tanh-normal actor over the config's network, logging each action's probability."""
    encoder = make_encoder(cfg.net)
    return make_gaussian_actor(
        action_spec, encoder, cfg.algo.hidden_sizes, cfg.device, return_log_prob=True
    )


class ToyLearner:
    """The training loop's learner (sharedspace.train.loop), one car per env or the crossing
    task's cars: one gradient step of REINFORCE per batch of ``num_envs`` x 8 steps."""

    def __init__(self, cfg, world, env):
        if isinstance(world, Cars):  # each car's policy, one set of weights for every car
            self.actor = make_car_actor(cfg, world.task)
            self.keys = (GROUP, "action"), ("next", GROUP, "reward")
        else:
            self.actor = make_actor(cfg, env.action_spec_unbatched)
            self.keys = "action", ("next", "reward")
        self.optimizer = torch.optim.Adam(self.actor.parameters(), lr=cfg.algo.lr)
        self.batch_frames = cfg.algo.num_envs * 8
        self.random_frames = 0

    def start(self, counters: dict[str, Any], logger) -> None:
        """Nothing before the first batch."""

    def step(self, data, counters: dict[str, Any]) -> dict[str, float]:
        action, reward = (data[k] for k in self.keys)
        log_prob = self.actor.get_dist(data).log_prob(action)
        reward = reward.reshape(log_prob.shape)
        loss = -(log_prob * (reward - reward.mean())).mean()
        self.optimizer.zero_grad()
        loss.backward()
        self.optimizer.step()
        counters["updates"] += 1
        return {"loss_pg": float(loss)}

    def state_dict(self) -> dict[str, Any]:
        return {}

    def optimizer_state(self) -> dict[str, Any]:
        return {"adam": self.optimizer.state_dict()}

    def load(self, ckpt: dict[str, Any]) -> None:
        self.actor.load_state_dict(ckpt["actor"])
        self.optimizer.load_state_dict(ckpt["optimizers"]["adam"])


@dataclass
class ToyPgConfig(AlgorithmConfig):
    """toy_pg's options: its own defaults."""

    num_envs: int = 4  # K, sub-envs stepped together
    reward: str = "learner"  # named reward (sharedspace.train.reward): world | learner
    # --- several cars (the crossing task's: sharedspace.marl.networks reads them)
    share_params: bool = True  # one network for every car (they are alike)
    init_scale: float = 0.4  # the policy's initial action standard deviation


def make_world(cfg):
    """One car per env, or the crossing task's cars, as the task says."""
    return Cars(cfg) if cfg.world.cars > 1 else OneCar(cfg)


def make_learner(cfg, world, env) -> ToyLearner:
    return ToyLearner(cfg, world, env)


register_algorithm(
    Algorithm(
        "toy_pg",
        __name__,
        cars="any",
        family="on",
        config=ToyPgConfig,
        doc="a toy",
    )
)
