"""Builders of the SAC(-GCN) pieces, TorchRL style: env, actor, critics, loss, buffer, collector."""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path
from typing import Any

import torch
from tensordict.nn import InteractionType, NormalParamExtractor, TensorDictModule
from torch import nn, optim
from torchrl.collectors import Collector
from torchrl.data import LazyTensorStorage, TensorDictReplayBuffer
from torchrl.envs import EnvBase
from torchrl.modules import ProbabilisticActor, ValueOperator
from torchrl.modules.distributions import TanhNormal
from torchrl.objectives import SoftUpdate
from torchrl.objectives.sac import SACLoss

from sharedspace.train.config import TrainConfig
from sharedspace.train.gcn import ActorNet, GraphEncoder, QNet
from sharedspace.train.update import SACUpdate

__all__ = [
    "OBS_KEYS",
    "make_env",
    "make_actor",
    "make_critic",
    "make_loss",
    "make_optimizers",
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
) -> EnvBase:
    """The batched env (ENV_CONTRACT.md) on the Rust server: the one at ``cfg.server_endpoint``
    or reached through ``cfg.zenoh_config``, else a ``sim-server`` this process starts on a free
    loopback port (:func:`sharedspace.local_server.shared_server`). ``variations`` (and fixed
    ``variation_seeds`` per sub-env): scene variations, SPEC 5.2.1; the trainer passes
    ``cfg.variations`` for its training env only."""
    from sharedspace.torchrl_env import RemoteBatchedEnv

    kwargs = dict(
        num_envs=num_envs or cfg.num_envs,
        max_agents=cfg.max_agents,
        split=split,
        seed=cfg.seed if seed is None else seed,
        scenario_order=scenario_order,
        pedestrian_model=cfg.pedestrian_model,
        variations=variations or None,
        variation_seeds=variation_seeds,
        vehicle_model=cfg.vehicle_model or None,
    )
    if cfg.scenario_pool:
        kwargs["pool"] = cfg.scenario_pool
    if cfg.zenoh_config:
        from sharedspace.client import SimClient

        settings = zenoh_file_settings(cfg.zenoh_config)
        client = SimClient(
            endpoint=None,
            prefix=cfg.server_prefix,
            mode=settings.pop("mode", "client"),
            config=settings,
        )
        return RemoteBatchedEnv(prefix=cfg.server_prefix, client=client, **kwargs)
    if cfg.server_endpoint:
        return RemoteBatchedEnv(endpoint=cfg.server_endpoint, prefix=cfg.server_prefix, **kwargs)
    from sharedspace.local_server import shared_server

    server = shared_server(
        [cfg.scenario_pool] if cfg.scenario_pool else [], cfg.server_params or None
    )
    return RemoteBatchedEnv(endpoint=server.endpoint, prefix=server.prefix, **kwargs)


def zenoh_file_settings(path: str) -> dict[str, Any]:
    """A zenoh JSON5 configuration file (such as deploy/trainer.json5) as the flat
    ``{"path/to/key": value}`` entries :class:`sharedspace.transport.Transport` takes."""
    import json5

    flat: dict[str, Any] = {}

    def walk(prefix: str, value: Any) -> None:
        if isinstance(value, dict) and value:
            for key, inner in value.items():
                walk(f"{prefix}/{key}" if prefix else key, inner)
        else:
            flat[prefix] = value

    walk("", json5.loads(Path(path).read_text()))
    return flat


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


def make_critic(cfg: TrainConfig, action_spec) -> ValueOperator:
    """``Q(s, a)``: its own graph encoder + MLP; SACLoss makes the two critics and targets."""
    net = QNet(_encoder(cfg), cfg.hidden_sizes, action_spec.shape[-1])
    return ValueOperator(net, in_keys=[*OBS_KEYS, "action"]).to(cfg.device)


def make_loss(cfg: TrainConfig, actor, critic) -> tuple[SACLoss, SoftUpdate]:
    """SAC loss (two critics, learned temperature, target entropy -|A|) and soft target update."""
    loss = SACLoss(
        actor_network=actor,
        qvalue_network=critic,
        num_qvalue_nets=2,
        loss_function=cfg.loss_function,
        alpha_init=cfg.alpha_init,
        delay_actor=False,
        delay_qvalue=True,
    )
    loss.make_value_estimator(gamma=cfg.gamma)
    return loss, SoftUpdate(loss, tau=cfg.tau)


def make_optimizers(cfg: TrainConfig, loss: SACLoss) -> dict[str, optim.Optimizer]:
    """Adam for the actor, the critics and ``log_alpha``."""
    return {
        "actor": optim.Adam(list(loss.actor_network_params.flatten_keys().values()), lr=cfg.lr),
        "critic": optim.Adam(list(loss.qvalue_network_params.flatten_keys().values()), lr=cfg.lr),
        "alpha": optim.Adam([loss.log_alpha], lr=cfg.lr),
    }


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
    ).to(cfg.device)


def make_replay_buffer(cfg: TrainConfig) -> TensorDictReplayBuffer:
    """Uniform replay over a preallocated (lazy) tensor storage of ``buffer_size`` transitions."""
    return TensorDictReplayBuffer(
        storage=LazyTensorStorage(cfg.buffer_size, device=cfg.device),
        batch_size=cfg.batch_size,
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
