"""The learner's env: the batched remote env of a config, and the one residual transform that
every learner (single-car and multi-car) puts between its policy and a scripted driver."""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

from tensordict import TensorDictBase
from torchrl.envs import EnvBase, Transform, TransformedEnv

from sharedspace.scripted import SCRIPTED
from sharedspace.train.algorithm_configs import Driving
from sharedspace.train.config import ConfigError
from sharedspace.wire.errors import BadRequest
from sharedspace.world_config import WorldConfig

__all__ = ["Driving", "ResidualAction", "make_env"]


def make_env(
    world: WorldConfig,
    split: str = "train",
    num_envs: int = 1,
    seed: int = 0,
    scenario_order: str = "random",
    variations: dict[str, Any] | None = None,
    variation_seeds: Sequence[int] | None = None,
    scenarios: Sequence[str] | None = None,
    driving: Driving = Driving(),  # noqa: B008 - frozen
) -> EnvBase:
    """The batched env (ENV_CONTRACT.md) of ``world.env_spec`` on the Rust server of
    ``world.connection()`` (an endpoint, a zenoh file, or a ``sim-server`` this process
    starts): ``num_envs`` sub-envs. ``variations`` (and fixed ``variation_seeds`` per sub-env):
    scene variations, SPEC 5.2.1; the trainer passes the world's ``variations`` for its
    training env only. ``scenarios``: sub-env ``k`` plays ``scenarios[k]`` (scenes of
    ``split``), in sequential order; a ``validation`` env, and a sequential ``train`` one, play
    :meth:`WorldConfig.scene_indices`'s scenes by name. With ``driving.base_driver`` the
    policy's action is a residual over that script (:class:`ResidualAction`)."""
    from sharedspace.torchrl_env import RemoteBatchedEnv

    spec = world.env_spec(split, seed, variations, driving.reward_weights)
    if scenarios is None and split != "test":
        if split == "validation" or scenario_order == "sequential":  # by name, in pool order
            pool = world.pool_scenes()
            scenarios = [pool[i]["name"] for i in world.scene_indices(split)]
    try:
        env = RemoteBatchedEnv(
            spec,
            num_envs,
            scenario_order=scenario_order,
            scenarios=scenarios,
            variation_seeds=variation_seeds,
            client=world.connection(),
        )
    except BadRequest as err:
        if "unknown pool" not in str(err):
            raise
        raise ConfigError(
            f"{err}: serve the run's pool (`sim-server serve --cfg 'pools:[...]'`; "
            'docs/ARCHITECTURE.md, "Validation, not test") or point the run at a server '
            "that does"
        ) from None
    if not driving.base_driver:
        return env
    return TransformedEnv(env, ResidualAction(driving.base_driver, scale=driving.residual_scale))


class ResidualAction(Transform):
    """Residual policy learning (Silver et al., 2018): on the way into the env,
    ``action <- clamp(script(observation) + scale * action, -1, 1)``, so a policy whose action
    is 0 drives exactly as the script does. The collected data keep the policy's own (residual)
    action: a learner learns the residual.

    Args:
        driver: a scripted driver's name (:data:`sharedspace.scripted.SCRIPTED`).
        group: the agent group of a multi-agent env (``"vehicle"``: its ``features``, ``mask``
            and ``action`` are nested under the group); ``""`` for the single-car env.
        scale: how much the policy's action weighs (multi-car learners use 2, so a residual of
            1 overrides the script's full braking).
    """

    def __init__(self, driver: str = "car_aware", group: str = "", scale: float = 1.0):
        if driver not in SCRIPTED:
            raise ValueError(f"unknown scripted driver {driver!r}: one of {sorted(SCRIPTED)}")
        self.keys = {k: (group, k) if group else k for k in ("features", "mask", "action")}
        super().__init__(in_keys_inv=[self.keys["action"]], out_keys_inv=[self.keys["action"]])
        self.driver_name = driver
        self.driver = SCRIPTED[driver]()
        self.group = group
        self.scale = float(scale)

    def _inv_call(self, tensordict: TensorDictBase) -> TensorDictBase:
        residual = tensordict.get(self.keys["action"])
        base = self.driver(tensordict.get(self.keys["features"]), tensordict.get(self.keys["mask"]))
        out = tensordict.clone(False)
        out.set(self.keys["action"], (base.to(residual.dtype) + self.scale * residual).clamp(-1, 1))
        return out

    def forward(self, tensordict: TensorDictBase) -> TensorDictBase:
        return tensordict
