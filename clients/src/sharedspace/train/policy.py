"""The networks every single-car algorithm builds on (paper Section IV.C): the encoder of a
config's registered ``network`` and the tanh-normal actor over it. SAC adds its Q-critics
(:mod:`sharedspace.train.sac`), PPO its state-value critic (:mod:`sharedspace.train.ppo`)."""

from __future__ import annotations

import math

import torch
from tensordict.nn import InteractionType, NormalParamExtractor, TensorDictModule
from torch import nn
from torchrl.modules import ProbabilisticActor
from torchrl.modules.distributions import TanhNormal

from sharedspace.train.gcn import ActorNet, FeatureNorm
from sharedspace.train.networks import NetworkConfig, get_network

__all__ = ["OBS_KEYS", "RESIDUAL_INIT_SCALE", "make_encoder", "make_gaussian_actor"]

#: Observation keys the networks read (ENV_CONTRACT.md).
OBS_KEYS = ["features", "adjacency", "mask"]

#: A residual policy's initial spread: the scale of its Gaussian before the tanh.
RESIDUAL_INIT_SCALE = 0.1


def make_encoder(net: NetworkConfig, norm: FeatureNorm | None = None) -> nn.Module:
    """The encoder of the registered network ``net.network`` (:mod:`sharedspace.train.networks`),
    built from a run's network part (:attr:`~sharedspace.train.config.TrainConfig.net`), with
    ``norm`` applied to its node features if given."""
    return get_network(net.network).make_encoder(net, norm).to(net.device)


class ActorParams(nn.Module):
    """Observation keys in, the Gaussian's ``(loc, scale)`` out (scale > 0 by a softplus that
    maps a raw 0 to 1)."""

    def __init__(self, net: ActorNet):
        super().__init__()
        self.net = net
        self.extract = NormalParamExtractor(scale_mapping="biased_softplus_1.0", scale_lb=1e-4)

    def forward(self, features, adjacency, mask):
        return self.extract(self.net(features, adjacency, mask))


def make_gaussian_actor(
    action_spec,
    encoder: nn.Module,
    hidden_sizes: list[int],
    device: str = "cpu",
    init_scale: float | None = None,
    return_log_prob: bool = False,
) -> ProbabilisticActor:
    """Encoder + MLP heads of ``hidden_sizes`` -> TanhNormal over the normalised action box
    ``[-1, 1]^2``, on ``device``. With
    ``init_scale`` the actor starts at ``loc`` 0 with that scale (:func:`start_at`);
    ``return_log_prob``: the collected data carry each action's log-probability (PPO)."""
    net = ActorParams(ActorNet(encoder, hidden_sizes, action_spec.shape[-1]))
    if init_scale is not None:
        start_at(net.net.head[-1], action_spec.shape[-1], init_scale)
    module = TensorDictModule(net, in_keys=OBS_KEYS, out_keys=["loc", "scale"])
    return ProbabilisticActor(
        module,
        in_keys=["loc", "scale"],
        spec=action_spec,
        distribution_class=TanhNormal,
        distribution_kwargs={"low": -1.0, "high": 1.0, "tanh_loc": False},
        default_interaction_type=InteractionType.RANDOM,
        return_log_prob=return_log_prob,
    ).to(device)


def start_at(last: nn.Linear, action_dim: int, scale: float) -> None:
    """The actor's output layer set so that it starts at ``loc`` = 0 (zero output weights and
    bias) and ``scale`` (its bias through ``biased_softplus_1.0``): a residual actor starts at
    its script."""
    with torch.no_grad():
        last.weight.zero_()
        last.bias.zero_()
        raw = math.log(math.expm1(scale)) - math.log(math.expm1(1.0))
        last.bias[action_dim:] = raw
