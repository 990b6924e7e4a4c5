"""Builders of the SAC(-GCN) pieces, TorchRL style: env, actor, critics, loss, buffer, collector."""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Any

import torch
from tensordict.nn import InteractionType, NormalParamExtractor, TensorDictModule
from torch import nn
from torchrl.collectors import Collector
from torchrl.data import LazyTensorStorage, TensorDictReplayBuffer
from torchrl.envs import EnvBase, Transform, TransformedEnv
from torchrl.modules import ProbabilisticActor, ValueOperator
from torchrl.modules.distributions import TanhNormal

from sharedspace.scripted import SCRIPTED
from sharedspace.train.config import TrainConfig
from sharedspace.train.gcn import ActorNet, GraphEncoder, QNet
from sharedspace.train.update import SACUpdate

__all__ = [
    "OBS_KEYS",
    "make_env",
    "make_actor",
    "make_critic",
    "make_update",
    "make_replay_buffer",
    "make_collector",
]

#: Observation keys the networks read (ENV_CONTRACT.md).
OBS_KEYS = ["features", "adjacency", "mask"]


def make_env(
    cfg: TrainConfig,
    split: str = "train",
    num_envs: int | None = None,
    seed: int | None = None,
    scenario_order: str = "random",
    variations: dict[str, Any] | None = None,
    variation_seeds: Sequence[int] | None = None,
    scenarios: Sequence[str] | None = None,
) -> EnvBase:
    """The batched env (ENV_CONTRACT.md) of ``cfg.env_spec`` on the Rust server of
    ``cfg.connection()`` (an endpoint, a zenoh file, or a ``sim-server`` this process starts).
    ``variations`` (and fixed ``variation_seeds`` per sub-env): scene variations, SPEC 5.2.1;
    the trainer passes ``cfg.variations`` for its training env only. ``scenarios``: sub-env
    ``k`` plays ``scenarios[k]`` (scenes of ``split``), in sequential order."""
    from sharedspace.torchrl_env import RemoteBatchedEnv

    env = RemoteBatchedEnv(
        cfg.env_spec(split, cfg.seed if seed is None else seed, variations),
        num_envs or cfg.num_envs,
        scenario_order=scenario_order,
        scenarios=scenarios,
        variation_seeds=variation_seeds,
        client=cfg.connection(),
    )
    if not cfg.base_driver:
        return env
    return TransformedEnv(env, ResidualAction(SCRIPTED[cfg.base_driver]()))


class ResidualAction(Transform):
    """Residual policy learning (Silver et al., 2018): the policy's ``action`` is added to a
    scripted driver's, and the env executes ``clamp(base(obs) + action, -1, 1)``. The learner
    sees the residual (its replay buffer stores what the policy chose), so a residual of 0 is
    the script itself; the deterministic residual of a fresh actor is about 0
    (:func:`make_actor` starts it there with a small spread)."""

    def __init__(self, base: nn.Module):
        super().__init__(in_keys_inv=["action"], out_keys_inv=["action"])
        self.base = base

    def _inv_call(self, tensordict):
        base = self.base(tensordict["features"], tensordict["mask"])
        return tensordict.set("action", (tensordict["action"] + base).clamp(-1.0, 1.0))


def _encoder(cfg: TrainConfig) -> GraphEncoder:
    return GraphEncoder(
        cfg.variant,
        cfg.max_agents,
        gcn_hidden=cfg.gcn_hidden,
        gcn_layers=cfg.gcn_layers,
        readout=cfg.readout,
    )


class _ActorParams(nn.Module):
    def __init__(self, net: ActorNet):
        super().__init__()
        self.net = net
        self.extract = NormalParamExtractor(scale_mapping="biased_softplus_1.0", scale_lb=1e-4)

    def forward(self, features, adjacency, mask):
        return self.extract(self.net(features, adjacency, mask))


def make_actor(cfg: TrainConfig, action_spec) -> ProbabilisticActor:
    """Graph encoder + MLP -> TanhNormal over the normalised action box ``[-1, 1]^2``."""
    net = _ActorParams(ActorNet(_encoder(cfg), cfg.hidden_sizes, action_spec.shape[-1]))
    if cfg.base_driver:
        _start_near_zero(net.net.head[-1], action_spec.shape[-1])
    module = TensorDictModule(net, in_keys=OBS_KEYS, out_keys=["loc", "scale"])
    return ProbabilisticActor(
        module,
        in_keys=["loc", "scale"],
        spec=action_spec,
        distribution_class=TanhNormal,
        distribution_kwargs={"low": -1.0, "high": 1.0, "tanh_loc": False},
        default_interaction_type=InteractionType.RANDOM,
        return_log_prob=False,
    ).to(cfg.device)


#: A residual policy's initial spread: the scale of its Gaussian before the tanh.
RESIDUAL_INIT_SCALE = 0.1


def _start_near_zero(last: nn.Linear, action_dim: int) -> None:
    """A residual actor starts at the script: ``loc`` = 0 (zero output weights and bias) and
    ``scale`` = :data:`RESIDUAL_INIT_SCALE` (its bias through ``biased_softplus_1.0``)."""
    with torch.no_grad():
        last.weight.zero_()
        last.bias.zero_()
        raw = math.log(math.expm1(RESIDUAL_INIT_SCALE)) - math.log(math.expm1(1.0))
        last.bias[action_dim:] = raw


def make_critic(cfg: TrainConfig, action_spec) -> ValueOperator:
    """``Q(s, a)``: its own graph encoder + MLP; SACLoss makes the two critics and targets."""
    net = QNet(
        _encoder(cfg), cfg.hidden_sizes, action_spec.shape[-1], layer_norm=cfg.critic_layer_norm
    )
    return ValueOperator(net, in_keys=[*OBS_KEYS, "action"]).to(cfg.device)


def make_update(cfg: TrainConfig, actor, action_spec, num_critics: int = 2) -> SACUpdate:
    """The learner: SAC's losses, target critics, optimisers and gradient step
    (:mod:`sharedspace.train.update`), training ``actor`` in place. Its critics are initialised
    like ``num_critics`` separate :func:`make_critic` networks."""
    qnets = [make_critic(cfg, action_spec).module for _ in range(num_critics)]
    return SACUpdate(
        actor,
        qnets,
        gamma=cfg.gamma,
        tau=cfg.tau,
        lr=cfg.lr,
        alpha_init=cfg.alpha_init,
        loss_function=cfg.loss_function,
        action_dim=action_spec.shape[-1],
        bc_weight=cfg.bc_weight,
        residual=bool(cfg.base_driver),
    ).to(cfg.device)


def make_replay_buffer(cfg: TrainConfig) -> TensorDictReplayBuffer:
    """Uniform replay over a preallocated (lazy) tensor storage of ``buffer_size`` transitions;
    its batches are the online part of a replay batch (all of it without prior data)."""
    prior_rows = round(cfg.batch_size * cfg.prior_ratio) if cfg.prior_data else 0
    return TensorDictReplayBuffer(
        storage=LazyTensorStorage(cfg.buffer_size, device=cfg.device),
        batch_size=cfg.batch_size - prior_rows,
    )


def make_collector(
    cfg: TrainConfig, env: EnvBase, actor, total_frames: int, init_random_frames: int
) -> Collector:
    """``Collector`` over the batched env: batches ``[K, frames_per_batch / K]``; done sub-envs
    are reset through ``step_and_maybe_reset`` (partial ``_reset``)."""
    return Collector(
        env,
        actor,
        frames_per_batch=cfg.batch_frames,
        total_frames=total_frames,
        init_random_frames=init_random_frames,
        device=cfg.device,
        env_device="cpu",
        auto_register_policy_transforms=False,  # the policy is not recurrent
    )


def seed_everything(seed: int) -> None:
    import random

    import numpy as np

    random.seed(seed)
    np.random.seed(seed % 2**32)  # noqa: NPY002 - seeds the global stream for third-party code
    torch.manual_seed(seed)
