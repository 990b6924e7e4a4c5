"""Gymnasium env: the one controlled vehicle of one server env, registered on import.

.. code-block:: python

    import gymnasium as gym
    import sharedspace  # registers the ids

    env = gym.make("sharedspace/SharedSpace-v0", endpoint="tcp/127.0.0.1:7447")
    obs, info = env.reset(seed=0)
    obs, reward, terminated, truncated, info = env.step(env.action_space.sample())

In a process that has not imported sharedspace (a vector env's worker), name the module in the
id: ``gym.make("sharedspace:sharedspace/SharedSpace-v0", ...)`` imports it first.

A thin adapter over :class:`~sharedspace.pettingzoo_env.SharedSpaceParallelEnv` with one
external agent (``agent``: ``vehicle_0``, the scenario's recorded car, by default; or a
pedestrian, ``agent="pedestrian_0"``, whose action is an acceleration in its own frame,
docs/MODEL.md 2b): the same observation dict
(``features [M, 11]``, ``adjacency [M, M]``, ``mask [M]``), action (normalised
``[acc, omega]`` in ``[-1, 1]``), reward and infos. The server truncates at the scenario's
horizon, so no ``TimeLimit`` is added.

**Lazy connection, picklable.** The server env is created on the first ``reset``, not in the
constructor, and pickling or copying keeps only the constructor's arguments: a copy (in this
process or in a vector env's worker process) opens its own connection and its own server env
when first reset. ``close()`` releases the server env; a closed env can be reset again.
"""

from __future__ import annotations

from typing import Any

import gymnasium

from .names import agent_group
from .spaces import action_space, observation_space

__all__ = ["SharedSpaceEnv", "ENV_ID", "register"]

#: The registered id (``gymnasium.make(ENV_ID, endpoint=...)``).
ENV_ID = "sharedspace/SharedSpace-v0"
#: The agent a Gymnasium env drives unless told: the scenario's recorded car.
DEFAULT_AGENT = "vehicle_0"
#: Options of the parallel env that are neither spec nor connection fields.
_PARALLEL_ONLY = ("scenario", "max_cycles", "render_size")


class SharedSpaceEnv(gymnasium.Env):
    """One server env's controlled vehicle as a Gymnasium env (see the module docstring).

    Takes what :class:`~sharedspace.pettingzoo_env.SharedSpaceParallelEnv` takes (a
    :class:`~sharedspace.wire.EnvSpec` and options naming its fields or ``Connection`` fields;
    ``scenario``, ``max_cycles``, ``render_size``) but ``external_agents`` (the one ``agent``)
    and ``client`` (a copy must be able to connect on its own). The options
    become the spec and the connection here, where they are checked.
    """

    metadata = {"render_modes": ["rgb_array"], "render_fps": 2}

    def __init__(
        self,
        render_mode: str | None = None,
        spec=None,
        agent: str = DEFAULT_AGENT,
        **options: Any,
    ):
        from .client import env_options

        agent_group(agent)  # a vehicle_{k} or pedestrian_{k}, or a ValueError naming it
        self.agent = agent
        for fixed in ("external_agents", "client"):
            if fixed in options:
                raise TypeError(f"SharedSpaceEnv does not take {fixed!r}")
        if render_mode not in (None, "rgb_array"):
            raise ValueError(f"render_mode must be None or 'rgb_array', got {render_mode!r}")
        self.render_mode = render_mode
        own = {k: options.pop(k) for k in _PARALLEL_ONLY if k in options}
        spec, connection, _ = env_options(options, spec)
        self._args: dict[str, Any] = {
            **own,
            "spec": spec.replace(external_agents=(agent,)),
            "client": connection,
            "render_mode": render_mode,
        }
        self.observation_space = observation_space(spec.max_agents)
        self.action_space = action_space()
        self._parallel = None

    def _env(self):
        if self._parallel is None:
            from .pettingzoo_env import SharedSpaceParallelEnv

            self._parallel = SharedSpaceParallelEnv(**self._args)
        return self._parallel

    @property
    def scenario(self) -> str | None:
        """The current episode's scenario name (``None`` before the first reset)."""
        return None if self._parallel is None else self._parallel.scenario

    def reset(self, *, seed: int | None = None, options: dict | None = None):
        super().reset(seed=seed)
        obs, infos = self._env().reset(seed=seed, options=options)
        return obs[self.agent], infos[self.agent]

    def step(self, action):
        if self._parallel is None:
            raise RuntimeError("call reset() before step()")
        a = self.agent
        obs, rewards, terms, truncs, infos = self._parallel.step({a: action})
        return obs[a], rewards[a], terms[a], truncs[a], infos[a]

    def render(self):
        return None if self._parallel is None else self._parallel.render()

    def close(self) -> None:
        if self._parallel is not None:
            self._parallel.close()
            self._parallel = None

    def __getstate__(self) -> dict[str, Any]:
        state = self.__dict__.copy()
        state["_parallel"] = None  # a copy connects on its own first reset
        return state

    def __deepcopy__(self, memo) -> SharedSpaceEnv:
        import copy

        new = self.__class__.__new__(self.__class__)
        new.__dict__.update(copy.deepcopy(self.__getstate__(), memo))
        return new


def register() -> None:
    """Registers :data:`ENV_ID` with Gymnasium (done on ``import sharedspace``)."""
    if ENV_ID not in gymnasium.registry:
        gymnasium.register(id=ENV_ID, entry_point="sharedspace.gym_env:SharedSpaceEnv")
