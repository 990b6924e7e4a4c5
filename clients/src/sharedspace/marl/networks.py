"""The multi-car learners' networks (TorchRL's ``MultiAgentMLP``): each car's observation (its
node features, flattened), the tanh-normal policy every algorithm shares, and the MLP its critics
are made of."""

from __future__ import annotations

import torch
from tensordict.nn import NormalParamExtractor, TensorDictModule, TensorDictSequential
from torch import nn
from torchrl.modules import MultiAgentMLP, ProbabilisticActor, TanhNormal

from sharedspace.marl.config import MarlConfig
from sharedspace.marl.task import CarObservation, CrossingTask
from sharedspace.names import NODE_FEATURES

__all__ = ["ACTION", "GROUP", "OBS", "agents_mlp", "make_actor", "observation"]

GROUP = "vehicle"
OBS = (GROUP, "observation")
ACTION = (GROUP, "action")


def observation() -> TensorDictModule:
    """Each car's flat observation (:class:`~sharedspace.marl.task.CarObservation`)."""
    return TensorDictModule(
        CarObservation(), in_keys=[(GROUP, "features"), (GROUP, "mask")], out_keys=[OBS]
    )


def agents_mlp(
    cfg: MarlConfig, task: CrossingTask, extra_inputs: int, outputs: int, centralized: bool
) -> MultiAgentMLP:
    """An MLP per car over its observation (plus ``extra_inputs``), or over every car's
    (``centralized``); one set of weights for every car with ``share_params``."""
    return MultiAgentMLP(
        n_agent_inputs=task.max_agents * (NODE_FEATURES + 1) + extra_inputs,
        n_agent_outputs=outputs,
        n_agents=task.cars,
        centralized=centralized,
        share_params=cfg.share_params,
        depth=cfg.depth,
        num_cells=cfg.hidden,
        activation_class=nn.Tanh,
    )


def make_actor(cfg: MarlConfig, task: CrossingTask) -> ProbabilisticActor:
    """Tanh-normal policy per car; at initialisation its mean is ~0 (the script's action, for a
    residual learner) and its standard deviation ``init_scale``."""
    mlp = agents_mlp(cfg, task, extra_inputs=0, outputs=4, centralized=False)
    with torch.no_grad():  # the last layer: mean and raw scale start near 0
        for p in list(mlp.parameters())[-2:]:  # the output layer's weight and bias
            p.mul_(0.01)
    head = TensorDictModule(
        nn.Sequential(mlp, NormalParamExtractor(scale_mapping=f"biased_softplus_{cfg.init_scale}")),
        in_keys=[OBS],
        out_keys=[(GROUP, "loc"), (GROUP, "scale")],
    )
    return ProbabilisticActor(
        module=TensorDictSequential(observation(), head),
        in_keys=[(GROUP, "loc"), (GROUP, "scale")],
        out_keys=[ACTION],
        distribution_class=TanhNormal,
        distribution_kwargs={"low": -1.0, "high": 1.0},
        return_log_prob=True,
    )
