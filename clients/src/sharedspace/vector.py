""":class:`VectorClient`: K envs of one ``CreateEnv`` stepped together over a
:class:`~sharedspace.client.SimClient`, one ``BatchStep`` per step (actions ``[K, n_ext, 2]``
float32), with failover.

Failover
--------
When the server hosting a :class:`VectorClient`'s envs dies (its liveliness token
``{p}/server/{id}/alive`` disappears, or a query to it gets no reply within the timeout), the
next ``step``/``reset`` raises :class:`~sharedspace.transport.ServerLost`. The envs and the
episodes in flight are gone with that server: nothing of them can be recovered.
:meth:`VectorClient.recreate` creates the same number of envs with the same ``CreateEnv``
parameters (same seed, so the scenario sequence restarts from the seed: the new server replays
the sequence from its first episode, not from where the lost one was) on the least-loaded
surviving server and resets them. With ``failover=True`` this happens inside ``step``: the
step returns a synthetic transition in which every env is **truncated** (reward 0, ``obs`` = the
last observation received before the loss), whose ``resets`` lists every env with its new
episode, like an autoreset step, and ``result["failover"]`` is True. Each
failover increments :attr:`VectorClient.failovers` and logs a warning on the ``sharedspace``
logger.
"""

from __future__ import annotations

import logging
from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np

from .client import Connection, SimClient, env_options
from .closing import Closing
from .names import REWARD_TERMS
from .transport import ServerLost
from .wire import requests
from .wire.envelope import encode, f32_array_head
from .wire.errors import EnvClosed, SharedspaceError, WrongShape
from .wire.replies import OBS_KEYS, decode_batch_result
from .wire.requests import EnvSpec

__all__ = ["VectorClient"]

log = logging.getLogger("sharedspace")


def _stack_reset_obs(results: Sequence[Mapping[str, Any]]) -> dict[str, np.ndarray]:
    return {
        key: np.stack([r["obs"][key] for r in results])
        for key in ("features", "adjacency", "mask", "node_ids")
    }


class VectorClient(Closing):
    """K envs of one :class:`~sharedspace.wire.EnvSpec`, created by one ``CreateEnv`` and
    stepped with one ``BatchStep`` per step.

    Args:
        num_envs: K.
        spec: the envs (default: the server's defaults); ``**options`` naming ``EnvSpec``
            fields are applied over it.
        client: a :class:`SimClient` to share, or the :class:`~sharedspace.client.Connection`
            to open (default: ``Connection`` fields of ``**options``).
        failover: on :class:`ServerLost`, re-create the envs on a surviving server inside
            ``step``/``reset`` (see the module docstring) instead of raising.
        step_timeout: timeout of a ``BatchStep`` (default: the client's timeout).
    """

    def __init__(
        self,
        num_envs: int,
        spec: EnvSpec | None = None,
        *,
        client: SimClient | Connection | None = None,
        failover: bool = False,
        step_timeout: float | None = None,
        **options: Any,
    ):
        if num_envs < 1:
            raise ValueError("num_envs must be at least 1")
        spec, where, wants_failover = env_options(options, spec, client)
        self._own_client = not isinstance(where, SimClient)
        self.client = where if isinstance(where, SimClient) else where.open()
        self.num_envs = int(num_envs)
        self.spec = spec
        self.failover = bool(failover or wants_failover)
        self.step_timeout = step_timeout
        #: Number of failovers so far (re-creations after a lost server).
        self.failovers = 0
        self.env_ids: list[str] = []
        self.server_id: str = ""
        self.created: dict[str, Any] = {}
        self._last_obs: dict[str, np.ndarray] | None = None
        self._closed = False
        try:
            self._create()
        except BaseException:
            if self._own_client:
                self.client.shutdown()
            raise

    # ----------------------------------------------------------------------------------------

    def _create(self, exclude: Sequence[str] = ()) -> None:
        sid = None
        if exclude:
            sid = str(self.client.pick_server(exclude=exclude, need=self.num_envs)["server_id"])
        self.created = self.client.create(self.num_envs, self.spec, server_id=sid)
        self.env_ids = list(self.created["env_ids"])
        self.server_id = self.created["server_id"]
        self.n_ext = len(self.created["external_agents"])
        self.external_agents = list(self.created["external_agents"])
        self.max_agents = int(self.created["observation"]["max_agents"])
        self._batch_key = self.client.transport.key("server", self.server_id, "batch", "step")
        # Every BatchStep is the map {env_ids, actions} with the same env ids and action shape:
        # everything but the action data is encoded once (a K = 256 request took 92 us to pack
        # whole, mostly the 256 strings; packing the actions array alone ~80 us right after
        # the blocking receive of the previous reply).
        self._batch_head = requests.batch_step_head(self.env_ids) + f32_array_head(
            (self.num_envs, self.n_ext, 2)
        )
        known = (encode(list(self.env_ids)), list(self.env_ids))
        self._decode_batch = lambda payload: decode_batch_result(payload, known)
        self._pending_step: dict[str, Any] | None = None
        self.n_features = int(self.created["observation"]["n_features"])

    @property
    def closed(self) -> bool:
        return self._closed

    def _check_open(self) -> None:
        if self._closed:
            raise EnvClosed("env_closed", "this VectorClient is closed")

    def recreate(self) -> list[dict[str, Any]]:
        """Re-creates the K envs with the same ``CreateEnv`` parameters on the least-loaded
        surviving server and resets them (the scenario sequence restarts from the seed; any
        episode in flight is lost). Returns the K ``ResetResult``s."""
        self._check_open()
        old_server, old_ids = self.server_id, list(self.env_ids)
        lost = [old_server] if not self.client.transport.is_alive(old_server) else []
        for e in old_ids:
            self.client.forget(e)
        try:
            self._create(exclude=lost or [old_server])
        except SharedspaceError:
            if lost:
                raise
            self._create()  # the old server is alive: it may host the new envs
        self.failovers += 1
        log.warning(
            "sharedspace: failover #%d: %d env(s) of server %s re-created on %s (%s.. -> %s..); "
            "episodes in flight are lost, scenario sequences restart from the seed",
            self.failovers,
            self.num_envs,
            old_server,
            self.server_id,
            old_ids[0] if old_ids else "-",
            self.env_ids[0],
        )
        return self._reset_all(None)

    def _reset_all(self, seed: int | None) -> list[dict[str, Any]]:
        seeds = None if seed is None else [int(seed) + k for k in range(self.num_envs)]
        results = self.client.reset_many(self.env_ids, seeds=seeds)
        self._pending_step = None
        self._last_obs = _stack_reset_obs(results)
        return results

    def reset(self, seed: int | None = None, env_index: Sequence[int] | None = None):
        """Resets every env (``env_index``: only those) and returns their ``ResetResult``s.
        ``seed`` re-seeds env k with ``seed + k``."""
        self._check_open()
        idx = list(range(self.num_envs)) if env_index is None else [int(i) for i in env_index]
        ids = [self.env_ids[i] for i in idx]
        seeds = None if seed is None else [int(seed) + i for i in idx]
        try:
            results = self.client.reset_many(ids, seeds=seeds)
        except ServerLost:
            if not self.failover:
                raise
            self.recreate()
            results = self.client.reset_many([self.env_ids[i] for i in idx], seeds=seeds)
        if env_index is None:
            self._pending_step = None
            self._last_obs = _stack_reset_obs(results)
        elif (start := self._start_obs()) is not None:
            for i, r in zip(idx, results, strict=True):
                for key in start:
                    start[key][i] = r["obs"][key]
        return results

    def step(self, actions: Any) -> dict[str, Any]:
        """One ``BatchStep`` of the K envs: ``actions`` ``[K, n_ext, 2]`` (a ``[K, 2]`` array is
        accepted when ``n_ext`` is 1). Returns the ``BatchStepResult`` (SPEC 6.5): numpy arrays
        ``obs`` ``features [K, n_ext, M, 11]`` etc., ``reward [K, n_ext]``, ``terminated``,
        ``truncated``, the per-env columns ``episode``, ``step``, ``t`` ``[K]`` and
        ``action_clipped [K, n_ext]``, ``scenario`` (K names), the ``events`` and ``metrics``
        of the envs that have some (each naming its env by ``index``), and ``resets``: the
        autoreset envs' ``index [R]`` and new episodes (``obs`` stacked ``[R, ...]``).
        After an autoreset the next step starts from ``resets.obs``; this step's ``obs`` is
        the terminal observation."""
        self._check_open()
        arr = np.asarray(actions, dtype=np.float32)
        if arr.ndim == 2 and self.n_ext == 1:
            arr = arr[:, None, :]
        want = (self.num_envs, self.n_ext, 2)
        if arr.shape != want:
            raise WrongShape(
                message=f"step: actions must have shape [K={want[0]}, n_ext={want[1]}, 2] "
                f"(float32 [acc, omega] in [-1, 1]), got {list(np.shape(actions))}",
            )
        payload = self._batch_head + np.ascontiguousarray(arr, dtype="<f4").tobytes()
        try:
            res = self.client.request(
                self.server_id,
                self._batch_key,
                payload,
                self.step_timeout,
                decode=self._decode_batch,
            )
        except ServerLost:
            if not self.failover:
                raise
            return self._failover_step()
        # The observations the next step starts from are only needed on failover (and for a
        # partial reset): kept as this reply's views, merged with its autoresets on demand.
        self._pending_step = res
        return res

    def _start_obs(self) -> dict[str, np.ndarray] | None:
        """Per env, the observation its next step starts from (after an autoreset: the new
        episode's first), as writable ``[K, n_ext, ...]`` arrays; None before any reset."""
        res, self._pending_step = self._pending_step, None
        if res is not None:
            obs = {k: np.array(res["obs"][k]) for k in OBS_KEYS}
            resets = res["resets"]
            if len(resets["index"]):
                for key in OBS_KEYS:
                    obs[key][resets["index"]] = resets["obs"][key]
            self._last_obs = obs
        return self._last_obs

    def _failover_step(self) -> dict[str, Any]:
        k, n = self.num_envs, self.n_ext
        prev = self._start_obs()
        resets = self.recreate()
        stacked = _stack_reset_obs(resets)
        obs = prev if prev is not None else stacked
        zeros = np.zeros((k, n), dtype=np.float32)
        return {
            "env_ids": list(self.env_ids),
            "obs": obs,
            "reward": zeros.copy(),
            "reward_terms": {t: zeros.copy() for t in REWARD_TERMS},
            "terminated": np.zeros((k, n), dtype=np.uint8),
            "truncated": np.ones((k, n), dtype=np.uint8),
            "episode": np.zeros(k, dtype=np.uint64),
            "scenario": [""] * k,
            "step": np.zeros(k, dtype=np.uint32),
            "t": np.zeros(k, dtype=np.float64),
            "action_clipped": np.zeros((k, n), dtype=np.uint8),
            "events": [],
            "metrics": [],
            "resets": {
                "index": np.arange(k, dtype=np.uint32),
                "episode": np.array([r["episode"] for r in resets], dtype=np.uint64),
                "scenario": [r["scenario"] for r in resets],
                "horizon_steps": np.array([r["horizon_steps"] for r in resets], dtype=np.uint32),
                "agents": [r["agents"] for r in resets],
                "obs": stacked,
            },
            "failover": True,
        }

    def close(self) -> None:
        """Closes the K envs (and the client if this VectorClient opened it)."""
        if self._closed:
            return
        self._closed = True
        try:
            self.client.close_many(self.env_ids)
        finally:
            if self._own_client:
                self.client.shutdown()
