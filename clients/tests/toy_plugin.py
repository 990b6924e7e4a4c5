"""A learner's plug-in from outside the package, as a user writes one: a toy network and a toy
algorithm, each registered once by importing this module. Nothing in ``sharedspace`` names
them (clients/tests/test_plugins.py trains and scores them).

- ``toy_mean``: the masked mean of each observation's scaled node features, then one layer;
- ``toy_pg``: a one-car policy gradient (REINFORCE with the batch's mean reward as baseline)
  on the tanh-normal actor over any registered network.
"""

from __future__ import annotations

from typing import Any

import torch
from torch import nn

from sharedspace.names import FEATURE_SCALE, NODE_FEATURES
from sharedspace.train.checkpoint import read_checkpoint, save_checkpoint
from sharedspace.train.envs import make_env
from sharedspace.train.evaluation import evaluate_split
from sharedspace.train.metrics import EpisodeTracker, MetricLogger
from sharedspace.train.networks import Network, register_network
from sharedspace.train.policy import make_encoder, make_gaussian_actor
from sharedspace.train.registry import Algorithm, register_algorithm
from sharedspace.train.run import seed_everything, start_run


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
    return make_gaussian_actor(cfg, action_spec, make_encoder(cfg), return_log_prob=True)


class _Learner:
    """What a checkpoint keeps of the learner: its optimiser."""

    def __init__(self, optimizer: torch.optim.Optimizer):
        self.optimizer = optimizer

    def state_dict(self) -> dict[str, Any]:
        return {}

    def optimizer_state(self) -> dict[str, Any]:
        return {"adam": self.optimizer.state_dict()}


def train(cfg, resume: str | None = None) -> dict[str, Any]:
    """Collects ``num_envs`` x 8 steps, one gradient step, until ``total_frames``."""
    log_dir = start_run(cfg)
    seed_everything(cfg.seed)
    env = make_env(cfg, split="train", variations=cfg.variations)
    actor = make_actor(cfg, env.action_spec_unbatched)
    optimizer = torch.optim.Adam(actor.parameters(), lr=cfg.lr)
    counters = {"frames": 0, "iterations": 0, "episodes": 0}
    if resume:
        ckpt = read_checkpoint(resume)
        actor.load_state_dict(ckpt["actor"])
        counters |= ckpt["counters"]
    logger, tracker = MetricLogger(log_dir, tensorboard=False), EpisodeTracker(cfg.num_envs)
    while counters["frames"] < cfg.total_frames:
        with torch.no_grad():
            data = env.rollout(8, actor, break_when_any_done=False)
        reward = data["next", "reward"].squeeze(-1)
        log_prob = actor.get_dist(data).log_prob(data["action"])
        loss = -(log_prob * (reward - reward.mean())).mean()
        optimizer.zero_grad()
        loss.backward()
        optimizer.step()
        counters["frames"] += data.numel()
        counters["iterations"] += 1
        counters["episodes"] += len(tracker.update(data))
        logger.log({"train/loss_pg": float(loss)}, counters["frames"])
    path = log_dir / "checkpoints" / "last.pt"
    save_checkpoint(path, cfg, actor, _Learner(optimizer), counters)
    summary = evaluate_split(cfg, actor, cfg.eval_split)["summary"] if cfg.eval_interval else {}
    env.close()
    logger.close()
    return {"counters": counters, "eval": summary}


register_algorithm(
    Algorithm(
        "toy_pg", __name__, family="on", defaults={"num_envs": 4, "reward": "learner"}, doc="a toy"
    )
)
