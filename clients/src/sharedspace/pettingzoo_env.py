"""PettingZoo ``ParallelEnv`` over one server env (a thin adapter over the client).

.. code-block:: python

    import sharedspace
    env = sharedspace.parallel_env(endpoint="tcp/127.0.0.1:7447", render_mode="rgb_array")
    obs, infos = env.reset(seed=42)
    while env.agents:
        actions = {a: env.action_space(a).sample() for a in env.agents}
        obs, rewards, terms, truncs, infos = env.step(actions)
    frame = env.render()          # uint8 [H, W, 3]
    env.close()

Agents are the external agents (``vehicle_0`` by default; names ``vehicle_{k}``). Each
observation is a dict ``features`` float32 ``[M, 11]``, ``adjacency`` float32 ``[M, M]`` and
``mask`` int8 ``[M]`` (``MultiBinary``); actions are float32 ``[2]`` in ``[-1, 1]`` (normalised
``[acc, omega]``). An agent leaves ``env.agents`` on the step it terminates or is truncated;
the episode is over when ``env.agents`` is empty (then call ``reset``).

``reset(seed=s)`` re-seeds the env's scenario sequence (same seed and actions → same episode);
``reset()`` continues it; ``options={"scenario": name}`` picks the scenario.

**Infos** are numbers only, with the same keys at ``reset`` and every ``step`` (:data:`INFO_KEYS`),
so that wrappers which turn infos into tensors (TorchRL's ``PettingZooWrapper``, SuperSuit)
take them as they are: ``step``, ``t``, ``scenario_index`` (position of the
scenario in the pool, as the server lists it: ``SimClient.scenarios``), ``action_clipped``,
``failover``, one ``reward_<term>`` per reward term, and the episode's metrics
(``success``, ``collision``, ``timeout``, ``episode_steps``, ``episode_return``, ``avg_speed``,
``avg_abs_jerk``, ``max_abs_acc``: 0 until the step that ends the agent's episode). Names travel
beside them: :attr:`SharedSpaceParallelEnv.scenario` (the current scenario's name),
:attr:`~SharedSpaceParallelEnv.episode` (the env's episode counter, which a seeded reset does
not restart), :attr:`~SharedSpaceParallelEnv.env_id`, :attr:`~SharedSpaceParallelEnv.server_id`,
:attr:`~SharedSpaceParallelEnv.horizon_steps`.
"""

from __future__ import annotations

import functools
import threading
import time
from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np
from gymnasium import spaces
from pettingzoo import ParallelEnv

from . import names
from . import spaces as _spaces
from .client import Connection, SimClient, env_options
from .render import render_observation
from .transport import undeclare_all
from .vector import VectorClient
from .wire.envelope import decode
from .wire.errors import EnvClosed, WrongShape
from .wire.requests import EnvSpec

__all__ = ["SharedSpaceParallelEnv", "env", "parallel_env", "ENV_NAME", "INFO_KEYS"]

ENV_NAME = "sharedspace_v1"
NODE_FEATURES = names.NODE_FEATURES
_REWARD_TERMS = names.REWARD_TERMS
_METRICS = ("episode_steps", "episode_return", "avg_speed", "avg_abs_jerk", "max_abs_acc")
#: The keys of every agent's info dict, at reset and at every step (all numbers).
INFO_KEYS = (
    "step",
    "t",
    "scenario_index",
    "action_clipped",
    "failover",
    *(f"reward_{t}" for t in _REWARD_TERMS),
    "success",
    "collision",
    "timeout",
    *_METRICS,
)


#: Attributes that hold a connection, a lock or a subscription: not pickled.
_LIVE_STATE = ("_vec", "_latest", "_latest_lock", "_subs", "_sub_env", "_client")


def _blank_info() -> dict[str, float | int | bool]:
    info: dict[str, float | int | bool] = dict.fromkeys(INFO_KEYS, 0.0)
    for key in ("step", "scenario_index", "episode_steps"):
        info[key] = 0
    for key in ("action_clipped", "failover", "success", "collision", "timeout"):
        info[key] = False
    return info


class SharedSpaceParallelEnv(ParallelEnv):
    """One server env as a PettingZoo ``ParallelEnv`` (see the module docstring).

    Args:
        spec: the server env (:class:`~sharedspace.wire.EnvSpec`: pool, split, seed, crowd
            model, ``max_agents`` M, ``external_agents`` (the learner's vehicles, ``vehicle_0``
            the scenario's ego), variations, traffic model, ...). ``**options`` naming its
            fields (``pool="hbs-general"``, ``variations={"position_sigma": 0.25}``) or
            :class:`~sharedspace.client.Connection` fields (``endpoint``, ``prefix``,
            ``timeout``, ``failover``: re-create the env on a surviving server when its server
            dies, the step returning every agent truncated) apply over it and ``client``.
        scenario: a scenario name (every episode plays it) or a list of names (each reset
            plays the next, cycling); ``reset(options={"scenario": name})`` overrides once.
        render_mode: ``None`` or ``"rgb_array"``; render_size: its picture's ``(H, W)``.
        max_cycles: truncate every agent after this many steps of an episode (PettingZoo's
            convention; ``None``: only the scenario's horizon, which the server enforces).
        client: a :class:`~sharedspace.client.SimClient` to share, or the ``Connection`` to
            open (default: ``tcp/127.0.0.1:7447``).

    ``env.variation`` is the episode's variation (seed and values; ``reset(options={"variation":
    seed})`` replays one). ``state()`` is the global state for centralised critics: every
    possible agent's observation flattened (``features``, ``adjacency``, ``mask``) and
    concatenated, zeros for an agent that has left; ``state_space`` is its ``Box``.
    """

    metadata = {
        "name": ENV_NAME,
        "render_modes": ["rgb_array"],
        "render_fps": 2,
        "is_parallelizable": True,
    }

    def __init__(
        self,
        spec: EnvSpec | None = None,
        *,
        scenario: str | Sequence[str] | None = None,
        render_mode: str | None = None,
        render_size: tuple[int, int] = (480, 480),
        max_cycles: int | None = None,
        client: SimClient | Connection | None = None,
        **options: Any,
    ):
        if render_mode not in (None, "rgb_array"):
            raise ValueError(f"render_mode must be None or 'rgb_array', got {render_mode!r}")
        self.render_mode = render_mode
        self.render_size = tuple(render_size)
        # A list of scenarios: each reset plays the next one (cycling); one name: pinned.
        self._scenario_list = (
            None if scenario is None or isinstance(scenario, str) else list(scenario)
        )
        if self._scenario_list == []:
            raise ValueError("scenario: an empty list")
        self._resets = 0
        spec, self._client, self._failover = env_options(options, spec, client)
        self.spec = spec.replace(
            scenario=scenario if isinstance(scenario, str) else None, autoreset=False
        )
        self._vec: VectorClient | None = None  # connected on first use (see _connected)
        self.max_agents = self.spec.max_agents
        if max_cycles is not None and int(max_cycles) < 1:
            raise ValueError(f"max_cycles must be at least 1, got {max_cycles}")
        self.max_cycles = None if max_cycles is None else int(max_cycles)
        self._cycles = 0
        self.possible_agents = list(self.spec.external_agents)
        self.agents: list[str] = []
        self._index = {a: i for i, a in enumerate(self.possible_agents)}
        self._closed = False
        self._obs: dict[str, np.ndarray] | None = None
        self._episode = 0
        self._step = 0
        #: The current scenario's name (``None`` before the first reset).
        self.scenario: str | None = None
        #: Steps of the current episode at which the server truncates (from the reset).
        self.horizon_steps: int | None = None
        #: Scenario name -> position in the pool, as the server lists it (at the first reset).
        self._scenario_index: dict[str, int] = {}
        self._agents_desc: dict[int, dict[str, Any]] = {}
        self._latest: dict[str, dict[str, Any]] = {}
        self._latest_lock = threading.Lock()
        self._subs: list[Any] = []
        self._sub_env = None
        #: What the last ``render()`` drew from: ``"publications"`` or ``"observation"``.
        self.render_source: str | None = None
        self._trails: dict[int, list[tuple[float, float]]] = {}

    @property
    def _connected(self) -> VectorClient:
        """The server env, created on first use: a constructed (or unpickled) env holds no
        connection until it is reset or asked for its ``env_id``."""
        if self._vec is None:
            self._check_open()
            self._vec = VectorClient(1, self.spec, client=self._client, failover=self._failover)
        return self._vec

    def __getstate__(self) -> dict[str, Any]:
        """The constructor's arguments and settings only: a copy creates its own server env
        (and its own connection) when first reset. A shared ``client`` is replaced by its
        :class:`~sharedspace.client.Connection`."""
        state = {k: v for k, v in self.__dict__.items() if k not in _LIVE_STATE}
        client = self._client
        state["_connection"] = (
            Connection.of_client(client, self._failover)
            if isinstance(client, SimClient)
            else client
        )
        return state

    def __setstate__(self, state: dict[str, Any]) -> None:
        self.__dict__.update(state)
        self._client = self.__dict__.pop("_connection")
        self._vec = None
        self._closed = False
        self.agents = []
        self._obs = None
        self._latest = {}
        self._latest_lock = threading.Lock()
        self._subs = []
        self._sub_env = None

    def __deepcopy__(self, memo) -> SharedSpaceParallelEnv:
        import copy

        new = self.__class__.__new__(self.__class__)
        new.__setstate__(copy.deepcopy(self.__getstate__(), memo))
        return new

    # ----------------------------------------------------------------------------------------
    # Spaces

    @functools.cache  # noqa: B019 - PettingZoo style: one object per agent
    def observation_space(self, agent: str) -> spaces.Dict:
        return _spaces.observation_space(self.max_agents)

    @functools.cache  # noqa: B019
    def action_space(self, agent: str) -> spaces.Box:
        return _spaces.action_space()

    @functools.cached_property
    def state_space(self) -> spaces.Box:
        """The ``Box`` of :meth:`state`: every possible agent's flattened observation."""
        m = self.max_agents
        return spaces.Box(
            -np.inf,
            np.inf,
            (len(self.possible_agents) * (m * NODE_FEATURES + m * m + m),),
            np.float32,
        )

    def state(self) -> np.ndarray:
        """The global state (see the class docstring) of the current step."""
        self._check_open()
        if self._obs is None:
            raise RuntimeError("call reset() before state()")
        parts = []
        for agent in self.possible_agents:
            e = self._index[agent]
            if agent in self.agents:
                parts += [
                    np.asarray(self._obs["features"][e], np.float32).ravel(),
                    np.asarray(self._obs["adjacency"][e], np.float32).ravel(),
                    np.asarray(self._obs["mask"][e], np.float32).ravel(),
                ]
            else:
                m = self.max_agents
                parts.append(np.zeros(m * NODE_FEATURES + m * m + m, np.float32))
        return np.concatenate(parts)

    # ----------------------------------------------------------------------------------------

    @property
    def episode(self) -> int:
        """The server env's episode counter (it counts every reset of this env)."""
        return self._episode

    @property
    def env_id(self) -> str:
        return self._connected.env_ids[0]

    @property
    def server_id(self) -> str:
        return self._connected.server_id

    @property
    def failovers(self) -> int:
        return 0 if self._vec is None else self._vec.failovers

    @property
    def client(self) -> SimClient:
        return self._connected.client

    def _check_open(self) -> None:
        if self._closed:
            raise EnvClosed("env_closed", "this sharedspace ParallelEnv is closed")

    def _agent_obs(self, obs: Mapping[str, np.ndarray], e: int) -> dict[str, np.ndarray]:
        """Agent ``e``'s observation, a copy inside its space's bounds (spaces.py says why)."""
        features, adjacency = _spaces.clip_observation(
            np.array(obs["features"][e], dtype=np.float32),
            np.array(obs["adjacency"][e], dtype=np.float32),
        )
        return {
            "features": features,
            "adjacency": adjacency,
            "mask": np.array(obs["mask"][e], dtype=np.int8),
        }

    def _take_reset(self, r: Mapping[str, Any]) -> tuple[dict, dict]:
        self._obs = {k: np.asarray(r["obs"][k]) for k in ("features", "adjacency", "mask")}
        self._episode = int(r["episode"])
        self._step = int(r["step"])
        self._agents_desc = {int(a["id"]): a for a in r.get("agents", ())}
        self.agents = list(self.possible_agents)
        self._cycles = 0
        self.scenario = r["scenario"]
        #: The episode's scene variation (``seed`` and the values applied), or None.
        self.variation = r.get("variation")
        self.horizon_steps = r.get("horizon_steps")
        info = self._info()
        obs = {a: self._agent_obs(self._obs, self._index[a]) for a in self.agents}
        return obs, {a: dict(info) for a in self.agents}

    def _info(self, t: float = 0.0) -> dict[str, float | int | bool]:
        if not self._scenario_index:
            _, names = self._connected.client.scenarios(self.spec.pool, self.server_id)
            self._scenario_index = {name: i for i, (name, _) in enumerate(names)}
        info = _blank_info()
        info["step"], info["t"] = self._step, t
        info["scenario_index"] = self._scenario_index.get(self.scenario, -1)
        return info

    def reset(self, seed: int | None = None, options: dict | None = None):
        self._check_open()
        if self.render_mode == "rgb_array" and self._sub_env != self.env_id:
            # Subscribe before the reset, so that its publication (step 0) is seen; the server
            # publishes only while it knows of a subscriber, which takes a moment to propagate.
            self._subscribe()
            time.sleep(0.3)
        scenario = (options or {}).get("scenario")
        variation = (options or {}).get("variation")
        if scenario is None and self._scenario_list:
            scenario = self._scenario_list[self._resets % len(self._scenario_list)]
        self._resets += 1
        if scenario is not None or variation is not None:
            r = self._connected.client.reset(
                self.env_id, seed=seed, scenario=scenario, variation=variation
            )
        else:
            r = self._connected.reset(seed=seed)[0]
        return self._take_reset(r)

    def step(self, actions: Mapping[str, Any]):
        self._check_open()
        if not self.agents:
            raise RuntimeError("the episode is over (env.agents is empty): call reset()")
        n = len(self.possible_agents)
        arr = np.zeros((1, n, 2), dtype=np.float32)
        for agent, act in actions.items():
            if agent not in self._index:
                raise KeyError(f"unknown agent {agent!r}; agents are {self.possible_agents}")
            a = np.asarray(act, dtype=np.float32)
            if a.shape != (2,):
                raise WrongShape(
                    message=f"action of {agent} must have shape [2] ([acc, omega]), "
                    f"got {list(a.shape)}",
                    env_id=self.env_id,
                )
            arr[0, self._index[agent]] = a
        res = self._connected.step(arr)
        live = list(self.agents)
        if res.get("failover"):
            obs = {a: self._agent_obs(self._obs, self._index[a]) for a in live}
            zero = dict.fromkeys(live, 0.0)
            self.agents = []
            if self.render_mode == "rgb_array":
                self._subscribe()
            info = self._info()
            info["failover"] = True
            return (
                obs,
                zero,
                dict.fromkeys(live, False),
                dict.fromkeys(live, True),
                {a: dict(info) for a in live},
            )
        o = res["obs"]
        self._obs = {k: o[k][0] for k in ("features", "adjacency", "mask")}
        self._step = int(res["step"][0])
        self._episode = int(res["episode"][0])
        t, clipped = float(res["t"][0]), res["action_clipped"][0]
        self.scenario = res["scenario"][0]
        reward = res["reward"][0]
        term = res["terminated"][0]
        trunc = res["truncated"][0]
        metrics = {m["metrics"]["agent"]: m["metrics"] for m in res["metrics"]}
        obs, rewards, terms, truncs, infos = {}, {}, {}, {}, {}
        for a in live:
            e = self._index[a]
            obs[a] = self._agent_obs(self._obs, e)
            rewards[a] = float(reward[e])
            terms[a] = bool(term[e])
            truncs[a] = bool(trunc[e])
            info = self._info(t)
            info["action_clipped"] = bool(clipped[e])
            for name, v in res["reward_terms"].items():
                info[f"reward_{name}"] = float(v[0][e])
            if a in metrics:
                m = metrics[a]
                outcome = m.get("outcome")
                for status in ("success", "collision", "timeout"):
                    info[status] = outcome == status
                info["episode_steps"] = int(m.get("steps", 0))
                for key in _METRICS[1:]:
                    info[key] = float(m.get(key, 0.0))
            infos[a] = info
        self._cycles += 1
        if self.max_cycles is not None and self._cycles >= self.max_cycles:
            truncs = {a: truncs[a] or not terms[a] for a in live}
        self.agents = [a for a in live if not (terms[a] or truncs[a])]
        return obs, rewards, terms, truncs, infos

    # ----------------------------------------------------------------------------------------
    # Rendering

    def _subscribe(self) -> None:
        undeclare_all(self._subs)
        t = self._connected.client.transport
        env_id = self.env_id
        self._subs = [
            t.declare_subscriber(t.key("env", env_id, topic), self._on_pub)
            for topic in ("states", "risk_graph")
        ]
        self._sub_env = env_id

    def _on_pub(self, sample) -> None:
        topic = str(sample.key_expr).rsplit("/", 1)[-1]
        try:
            msg = decode(sample.payload.to_bytes())
        except Exception:  # noqa: BLE001 - best effort
            return
        with self._latest_lock:
            self._latest[topic] = msg

    def _current(self, topic: str) -> dict[str, Any] | None:
        with self._latest_lock:
            msg = self._latest.get(topic)
        if (
            msg is not None
            and msg.get("env_id") == self.env_id
            and int(msg.get("episode", -1)) == self._episode
            and int(msg.get("step", -1)) == self._step
        ):
            return msg
        return None

    def render(self) -> np.ndarray | None:
        """``rgb_array``: a top-down picture of the scene (uint8 ``[H, W, 3]``) with the risk
        graph's edges, from the env's ``states`` / ``risk_graph`` publications; when they have
        not arrived (best effort, 0.5 s) the ego observation graph of the first agent."""
        if self.render_mode is None:
            return None
        self._check_open()
        if self._obs is None:
            raise RuntimeError("call reset() before render()")
        frame = self.scene_frame()
        if frame is not None:
            from .scene_plot import scene_rgb

            self.render_source = "publications"
            return scene_rgb(frame, size=self.render_size)
        self.render_source = "observation"
        return render_observation(
            self._obs["features"][0],
            self._obs["adjacency"][0],
            self._obs["mask"][0],
            size=self.render_size,
        )

    def scene_frame(self, wait_s: float = 0.5):
        """The current step's scene as a :class:`~sharedspace.scene_plot.Frame` (every agent,
        the controlled vehicles' goals and trails, the risk graph, time and step) from the
        server's ``states`` / ``risk_graph`` publications, or None when they have not arrived
        within ``wait_s`` (``render_mode="rgb_array"`` subscribes to them)."""
        from .scene_plot import frame_from_publications

        deadline = time.monotonic() + wait_s
        states = graph = None
        while time.monotonic() < deadline:
            states, graph = self._current("states"), self._current("risk_graph")
            if states is not None and graph is not None:
                break
            time.sleep(0.005)
        if states is None:
            return None
        ids = [int(i) for i in np.asarray(states["ids"]).tolist()]
        pos = np.asarray(states["positions"], dtype=np.float64).reshape(-1, 2)
        if int(states.get("step", 0)) == 0:
            self._trails = {}
        for k, aid in enumerate(ids):
            trail = self._trails.setdefault(aid, [])
            if not trail or trail[-1] != (float(pos[k, 0]), float(pos[k, 1])):
                trail.append((float(pos[k, 0]), float(pos[k, 1])))
            del trail[:-12]
        return frame_from_publications(
            {**states, "t": states.get("t", self._step * 0.5)},
            graph,
            self._agents_desc,
            trails={aid: list(t) for aid, t in self._trails.items() if aid in ids},
            note=self.scenario or "",
        )

    def close(self) -> None:
        if self._closed:
            return
        self._closed = True
        undeclare_all(self._subs)
        if self._vec is not None:
            self._vec.close()


def parallel_env(**kwargs: Any) -> SharedSpaceParallelEnv:
    """A :class:`SharedSpaceParallelEnv` (PettingZoo's ``parallel_env`` convention)."""
    return SharedSpaceParallelEnv(**kwargs)


def env(**kwargs: Any):
    """The same env as an AEC env (PettingZoo's ``env()`` convention, through PettingZoo's own
    ``parallel_to_aec``): agents act in turn and the server steps once all have."""
    from pettingzoo.utils.conversions import parallel_to_aec

    return parallel_to_aec(SharedSpaceParallelEnv(**kwargs))
