"""The multi-car learners' networks (TorchRL's ``MultiAgentMLP``): each car's observation, the
tanh-normal policy every algorithm shares, and the MLP its critics are made of.

A car's observation enters either flattened (its node features and mask, :class:`CarObservation`;
``network=""``, the default, what the shipped crossing policies were trained with) or through
a registered network's encoder (:mod:`sharedspace.train.networks`; ``network=gcn_risk`` puts the
GCN over each car's own risk graph in front of every car's MLP), one encoder per module."""

from __future__ import annotations

import dataclasses

import torch
from tensordict.nn import NormalParamExtractor, TensorDictModule, TensorDictSequential
from torch import nn
from torchrl.modules import MultiAgentMLP, ProbabilisticActor, TanhNormal

from sharedspace.marl.task import CarObservation, CrossingTask
from sharedspace.names import NODE_FEATURES
from sharedspace.train.config import TrainConfig
from sharedspace.train.networks import NetworkConfig, get_network

__all__ = ["ACTION", "GROUP", "OBS", "agents_mlp", "make_actor", "observation"]

GROUP = "vehicle"
OBS = (GROUP, "observation")
ACTION = (GROUP, "action")
#: Each car's observation keys (ENV_CONTRACT.md, grouped).
CAR_KEYS = [(GROUP, "features"), (GROUP, "adjacency"), (GROUP, "mask")]


def observation(cfg: TrainConfig | None = None, task: CrossingTask | None = None):
    """Each car's observation as one vector at :data:`OBS`: flattened
    (:class:`~sharedspace.marl.task.CarObservation`), or ``cfg.net.network``'s encoding."""
    if cfg is None or not cfg.net.network:
        return TensorDictModule(
            CarObservation(), in_keys=[(GROUP, "features"), (GROUP, "mask")], out_keys=[OBS]
        )
    encoder = get_network(cfg.net.network).make_encoder(_car_network(cfg, task), None)
    # an encoder maps [*, M, F] to [*, D]: over the group, every car's [*, A, M, F] at once
    return TensorDictModule(encoder, in_keys=CAR_KEYS, out_keys=[OBS])


def _car_network(cfg: TrainConfig, task: CrossingTask) -> NetworkConfig:
    """The network part of ``cfg`` for one car of ``task``."""
    return dataclasses.replace(cfg.net, max_agents=task.max_agents, device="cpu")


def observation_size(cfg: TrainConfig, task: CrossingTask) -> int:
    """The length of one car's :func:`observation` vector."""
    if not cfg.net.network:
        return task.max_agents * (NODE_FEATURES + 1)
    encoder = get_network(cfg.net.network).make_encoder(_car_network(cfg, task), None)
    return int(encoder.out_features)


def agents_mlp(
    cfg: TrainConfig, task: CrossingTask, extra_inputs: int, outputs: int, centralized: bool
) -> MultiAgentMLP:
    """An MLP per car over its observation (plus ``extra_inputs``), or over every car's
    (``centralized``); one set of weights for every car with ``share_params``."""
    return MultiAgentMLP(
        n_agent_inputs=observation_size(cfg, task) + extra_inputs,
        n_agent_outputs=outputs,
        n_agents=task.cars,
        centralized=centralized,
        share_params=cfg.algo.share_params,
        num_cells=list(cfg.algo.hidden_sizes),
        activation_class=nn.Tanh,
    )


def make_actor(cfg: TrainConfig, task: CrossingTask) -> ProbabilisticActor:
    """Tanh-normal policy per car; at initialisation its mean is ~0 (the script's action, for a
    residual learner) and its standard deviation ``init_scale``."""
    mlp = agents_mlp(cfg, task, extra_inputs=0, outputs=4, centralized=False)
    with torch.no_grad():  # the last layer: mean and raw scale start near 0
        for p in list(mlp.parameters())[-2:]:  # the output layer's weight and bias
            p.mul_(0.01)
    head = TensorDictModule(
        nn.Sequential(
            mlp, NormalParamExtractor(scale_mapping=f"biased_softplus_{cfg.algo.init_scale}")
        ),
        in_keys=[OBS],
        out_keys=[(GROUP, "loc"), (GROUP, "scale")],
    )
    return ProbabilisticActor(
        module=TensorDictSequential(observation(cfg, task), head),
        in_keys=[(GROUP, "loc"), (GROUP, "scale")],
        out_keys=[ACTION],
        distribution_class=TanhNormal,
        distribution_kwargs={"low": -1.0, "high": 1.0},
        return_log_prob=True,
    )
