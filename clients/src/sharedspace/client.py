"""Request/reply clients of the sharedspace server (protocol/SPEC.md section 5).

- :class:`SimClient`: one trainer's connection (a :class:`~sharedspace.transport.Transport`
  with its liveliness token). Creates envs (K in one ``CreateEnv``) on the least-loaded server
  and remembers which server owns each env; ``reset``, ``step``, ``batch_step`` and ``close``
  take and return numpy arrays (the decoded messages of the spec, arrays as numpy views).
- :class:`VectorClient`: K envs of one ``CreateEnv`` stepped together, one ``BatchStep`` per
  step (actions ``[K, n_ext, 2]`` float32), with failover.

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
import time
from collections.abc import Mapping, Sequence
from typing import Annotated, Any, Literal

import msgspec
import numpy as np

from . import codec, names
from .errors import EnvClosed, NoServer, ProtocolError, SharedspaceError, WrongShape
from .transport import (
    CREATE_TIMEOUT,
    DEFAULT_ENDPOINT,
    DEFAULT_PREFIX,
    DEFAULT_TIMEOUT,
    QueryFailed,
    ServerLost,
    Transport,
)

__all__ = ["SimClient", "VectorClient", "REWARD_TERMS"]

log = logging.getLogger("sharedspace")

REWARD_TERMS = names.REWARD_TERMS

#: Seconds a request's liveliness pre-check may rely on the last read of the server watch.
_ALIVE_MAX_AGE = 0.05


_OBS_KEYS = ("features", "adjacency", "mask", "node_ids")
_F4 = np.dtype("<f4")
_RESULT_ARRAYS = ("reward", "terminated", "truncated")
#: The per-env columns of a ``BatchStepResult``, and of its stacked ``resets``.
_BATCH_COLUMNS = ("episode", "step", "t", "action_clipped")
_RESET_COLUMNS = ("index", "episode", "horizon_steps")
#: Wire dtype -> (numpy dtype, item size), resolved once: ``np.dtype("<f4")`` per array is a
#: measurable share of decoding a small step reply.
_WIRE_DTYPES = {name: (np.dtype(name), size) for name, size in codec.ARRAY_DTYPES.items()}


def _array(m: Any) -> np.ndarray:
    """A binary-array map as a read-only numpy view (lean twin of ``codec.decode_array``, which
    it falls back to for anything unusual so that errors stay precise)."""
    if type(m) is dict:
        spec = _WIRE_DTYPES.get(m.get("dtype"))
        shape = m.get("shape")
        data = m.get("data")
        if spec is not None and type(shape) is list and type(data) is bytes:
            dtype, size = spec
            if len(shape) == 1:
                if type(shape[0]) is int and len(data) == shape[0] * size:
                    return np.frombuffer(data, dtype)
            else:
                count = 1
                for d in shape:
                    count *= d
                if type(count) is int and len(data) == count * size and min(shape, default=0) >= 0:
                    return np.ndarray(shape, dtype, data)
    if not codec.is_array_map(m):
        raise ProtocolError(f"expected a binary-array map {{dtype, shape, data}}, got {m!r:.80}")
    return codec.decode_array(m)


def _obs_in(r: Any) -> None:
    if type(r) is dict:
        obs = r.get("obs")
        if type(obs) is dict:
            for k in _OBS_KEYS:
                if k in obs:
                    obs[k] = _array(obs[k])


#: Untyped MessagePack decoder of replies: the same dicts, lists, str and bytes as
#: ``msgpack.unpackb(raw=False)``, built faster (a K = 256 batch reply: 1.31 -> 0.93 ms; a
#: single step's: 35 -> 19 us; docs/BENCHMARKS.md section 3, in its git history).
_REPLY_DECODER = msgspec.msgpack.Decoder()


def decode_result(payload: bytes) -> Any:
    """Decodes a reply envelope like :func:`sharedspace.codec.decode_reply`, faster on the hot
    path: MessagePack is decoded by msgspec without a per-map hook and only the binary arrays of
    ``ResetResult``/``StepResult``/``BatchStepResult`` (``obs``, ``reward``, ``reward_terms``,
    ``terminated``, ``truncated``, the autoreset ``reset.obs``, a batch's per-env columns and its
    stacked ``resets``) become numpy views; any other map is left as it is (``ServerInfo``,
    ``EnvCreated`` and ``Closed`` carry no arrays)."""
    if len(payload) == 0:
        raise ProtocolError("empty reply payload")
    try:
        msg = _REPLY_DECODER.decode(payload)
    except msgspec.DecodeError as e:  # truncated, trailing bytes, malformed
        raise ProtocolError(f"undecodable reply: {e}") from e
    r = codec.unwrap_reply(msg)
    if type(r) is dict and "obs" in r:
        _obs_in(r)
        for k in _RESULT_ARRAYS:
            if k in r:
                r[k] = _array(r[k])
        terms = r.get("reward_terms")
        if type(terms) is dict:
            for k, v in terms.items():
                terms[k] = _array(v)
        reset = r.get("reset")
        if "env_ids" in r:  # BatchStepResult: per-env columns, stacked autoresets
            for k in _BATCH_COLUMNS:
                if k in r:
                    r[k] = _array(r[k])
            if type(reset := r.get("resets")) is dict:
                for k in _RESET_COLUMNS:
                    if k in reset:
                        reset[k] = _array(reset[k])
        _obs_in(reset)
    return r


class _Arr(msgspec.Struct):
    """A binary array whose data stays in the reply buffer (typed decoding: no copy)."""

    dtype: str
    shape: tuple[int, ...]
    data: memoryview


class _Obs(msgspec.Struct):
    features: _Arr
    adjacency: _Arr
    mask: _Arr
    node_ids: _Arr


class _Resets(msgspec.Struct):
    index: _Arr
    episode: _Arr
    scenario: list[str]
    horizon_steps: _Arr
    agents: list[list[dict[str, Any]]]
    obs: _Obs
    variation: list[int | None] = []


class _Batch(msgspec.Struct):
    # Undecoded: the envs of a VectorClient's reply are its own, known to it (256 strings
    # fewer to build per K = 256 step).
    env_ids: msgspec.Raw
    obs: _Obs
    reward: _Arr
    reward_terms: dict[str, _Arr]
    terminated: _Arr
    truncated: _Arr
    episode: _Arr
    scenario: list[str]
    step: _Arr
    t: _Arr
    action_clipped: _Arr
    events: list[dict[str, Any]]
    metrics: list[dict[str, Any]]
    resets: _Resets


class _BatchReply(msgspec.Struct):
    ok: _Batch | None = None


_BATCH_DECODER = msgspec.msgpack.Decoder(_BatchReply)
_STR_LIST_DECODER = msgspec.msgpack.Decoder(list[str])


#: (wire dtype, shape) -> (numpy dtype, data bytes), for the shapes seen so far: a client gets
#: the same few shapes reply after reply, and checking one costs more than the view itself.
_VIEW_SPECS: dict[tuple[str, tuple[int, ...]], tuple[np.dtype, int]] = {}


def _view_spec(dtype: str, shape: tuple[int, ...]) -> tuple[np.dtype, int]:
    spec = _WIRE_DTYPES.get(dtype)
    if spec is None:
        raise ProtocolError(
            f"binary array: unsupported dtype {dtype!r} (allowed {list(_WIRE_DTYPES)})"
        )
    if min(shape, default=0) < 0:
        raise ProtocolError(f"binary array: shape {list(shape)} must be non-negative")
    count = 1
    for d in shape:
        count *= d
    if len(_VIEW_SPECS) >= 1024:
        _VIEW_SPECS.clear()
    out = _VIEW_SPECS[(dtype, shape)] = (spec[0], count * spec[1])
    return out


def _view(a: _Arr) -> np.ndarray:
    shape = a.shape
    dtype, nbytes = _VIEW_SPECS.get((a.dtype, shape)) or _view_spec(a.dtype, shape)
    if len(a.data) != nbytes:
        raise ProtocolError(
            f"binary array: data has {len(a.data)} bytes, shape {list(shape)} of {a.dtype} "
            f"needs {nbytes}"
        )
    if len(shape) == 1:
        return np.frombuffer(a.data, dtype)
    return np.ndarray(shape, dtype, a.data)


def _obs_views(o: _Obs) -> dict[str, np.ndarray]:
    return {
        "features": _view(o.features),
        "adjacency": _view(o.adjacency),
        "mask": _view(o.mask),
        "node_ids": _view(o.node_ids),
    }


def decode_batch_result(
    payload: bytes, known_ids: tuple[bytes, list[str]] | None = None
) -> dict[str, Any]:
    """Decodes a ``Reply<BatchStepResult>`` into the dict :func:`decode_result` gives, through
    msgspec's typed decoding: the arrays are numpy views of ``payload`` itself (no copy of the
    ~200 KB of a K = 256 reply) and no key strings are built for the fixed maps. With
    ``known_ids`` (the MessagePack encoding of the env ids the request named, and the ids),
    ``env_ids`` is that list when the reply's encoding is the same bytes. An error reply, or
    anything that does not match the schema, goes through :func:`decode_result`, which raises
    the precise error."""
    try:
        b = _BATCH_DECODER.decode(payload).ok
        if b is not None:
            raw_ids = bytes(b.env_ids)
            if known_ids is not None and raw_ids == known_ids[0]:
                env_ids = list(known_ids[1])
            else:
                env_ids = _STR_LIST_DECODER.decode(raw_ids)
    except (msgspec.DecodeError, msgspec.ValidationError):
        b = None
    if b is None:
        return decode_result(payload)
    r = b.resets
    resets = {
        "index": _view(r.index),
        "episode": _view(r.episode),
        "scenario": r.scenario,
        "horizon_steps": _view(r.horizon_steps),
        "agents": r.agents,
        "obs": _obs_views(r.obs),
    }
    if r.variation:  # absent on the wire when no reset env has variations
        resets["variation"] = r.variation
    return {
        "env_ids": env_ids,
        "obs": _obs_views(b.obs),
        "reward": _view(b.reward),
        "reward_terms": {k: _view(v) for k, v in b.reward_terms.items()},
        "terminated": _view(b.terminated),
        "truncated": _view(b.truncated),
        "episode": _view(b.episode),
        "scenario": b.scenario,
        "step": _view(b.step),
        "t": _view(b.t),
        "action_clipped": _view(b.action_clipped),
        "events": b.events,
        "metrics": b.metrics,
        "resets": resets,
    }


_NIL = msgspec.Raw(b"\xc0")


class _Step(msgspec.Struct):
    env_id: str
    episode: int
    scenario: str
    step: int
    t: float
    obs: _Obs
    reward: _Arr
    reward_terms: dict[str, _Arr]
    terminated: _Arr
    truncated: _Arr
    info: dict[str, Any]
    # Undecoded: a step with an autoreset (rare) is decoded by the generic path.
    reset: msgspec.Raw = _NIL


class _StepReply(msgspec.Struct):
    ok: _Step | None = None


_STEP_DECODER = msgspec.msgpack.Decoder(_StepReply)


def decode_step_result(payload: bytes) -> dict[str, Any]:
    """Decodes a ``Reply<StepResult>`` into the dict :func:`decode_result` gives, like
    :func:`decode_batch_result`: typed decoding, arrays as views of ``payload``. A step that
    carries an autoreset (once an episode), an error reply, or anything off the schema goes
    through :func:`decode_result`."""
    try:
        r = _STEP_DECODER.decode(payload).ok
    except (msgspec.DecodeError, msgspec.ValidationError):
        r = None
    if r is None or r.reset != _NIL:
        return decode_result(payload)
    return _step_dict(
        r,
        _obs_views(r.obs),
        _view(r.reward),
        {k: _view(v) for k, v in r.reward_terms.items()},
        _view(r.terminated),
        _view(r.truncated),
    )


def _step_dict(r, obs, reward, reward_terms, terminated, truncated) -> dict[str, Any]:
    """The ``StepResult`` dict of a typed step ``r`` (no autoreset) and its arrays."""
    return {
        "env_id": r.env_id,
        "episode": r.episode,
        "scenario": r.scenario,
        "step": r.step,
        "t": r.t,
        "obs": obs,
        "reward": reward,
        "reward_terms": reward_terms,
        "terminated": terminated,
        "truncated": truncated,
        "info": r.info,
        "reset": None,
    }


def _fixed_array_type(name: str, dtype: str, shape: tuple[int, ...]) -> type:
    """A struct type that accepts exactly one binary array: this dtype, this shape, and data of
    the matching length, all checked by msgspec while it decodes."""
    nbytes = _WIRE_DTYPES[dtype][1]
    for d in shape:
        nbytes *= d
    dims = tuple(Literal[d] for d in shape)
    return msgspec.defstruct(
        name,
        [
            ("dtype", Literal[dtype]),
            ("shape", tuple[dims] if dims else tuple[()]),
            ("data", Annotated[memoryview, msgspec.Meta(min_length=nbytes, max_length=nbytes)]),
        ],
    )


#: The array layout of an env's step replies: ``(name, dtype, shape)`` of each observation
#: array, then ``(dtype, shape)`` of ``reward``, ``terminated``, ``truncated`` and of every
#: reward term.
_Layout = tuple


def _layout_of(res: Mapping[str, Any]) -> _Layout:
    """The array layout of the decoded ``StepResult`` ``res`` (raises ``ValueError`` when its
    reward terms differ in layout, ``KeyError``/``AttributeError`` when it has no arrays)."""

    def spec(a: np.ndarray) -> tuple[np.dtype, tuple[int, ...]]:
        return a.dtype, tuple(a.shape)

    o = res["obs"]
    terms = {spec(v) for v in res["reward_terms"].values()}
    if len(terms) > 1:
        raise ValueError("reward terms of several layouts")
    reward = spec(res["reward"])
    return (
        tuple((k, *spec(o[k])) for k in _OBS_KEYS),
        reward,
        spec(res["terminated"]),
        spec(res["truncated"]),
        terms.pop() if terms else reward,
    )


class _StepLayout:
    """Decoder of the step replies of envs whose arrays have one fixed layout (dtype and shape
    of every array, set at ``CreateEnv`` by ``n_ext`` and ``max_agents``). msgspec checks the
    whole layout while it decodes, so the arrays are made without a check of their own: on
    this VM a step's client work after the ~300 µs wait for its reply is a measurable share of
    the round trip. Any reply off the layout (an autoreset, an error, another shape) goes
    through :func:`decode_step_result`, which gives the same dict or the precise error."""

    __slots__ = ("decoder", "obs", "reward", "terminated", "truncated", "term")

    def __init__(self, layout: _Layout):
        self.obs, self.reward, self.terminated, self.truncated, self.term = layout

        def arr(name: str, s: tuple[np.dtype, tuple[int, ...]]) -> type:
            return _fixed_array_type(name, s[0].str, s[1])

        obs_t = msgspec.defstruct(
            "_LayoutObs", [(k, arr(f"_Layout_{k}", (d, s))) for k, d, s in self.obs]
        )
        step_t = msgspec.defstruct(
            "_LayoutStep",
            [
                ("env_id", str),
                ("episode", int),
                ("scenario", str),
                ("step", int),
                ("t", float),
                ("obs", obs_t),
                ("reward", arr("_LayoutReward", self.reward)),
                ("reward_terms", dict[str, arr("_LayoutTerm", self.term)]),
                ("terminated", arr("_LayoutTerminated", self.terminated)),
                ("truncated", arr("_LayoutTruncated", self.truncated)),
                ("info", dict[str, Any]),
                ("reset", msgspec.Raw, _NIL),
            ],
        )
        reply_t = msgspec.defstruct("_LayoutReply", [("ok", step_t | None, None)])
        self.decoder = msgspec.msgpack.Decoder(reply_t)

    def __call__(self, payload: bytes) -> dict[str, Any]:
        try:
            r = self.decoder.decode(payload).ok
        except (msgspec.DecodeError, msgspec.ValidationError):
            r = None
        if r is None or r.reset != _NIL:
            return decode_step_result(payload)
        nd = np.ndarray
        o = r.obs
        # (key, dtype, shape) of each observation array; (dtype, shape) of the others.
        (kf, df, sf), (ka, da, sa), (km, dm, sm), (kn, dn, sn) = self.obs
        (d_rew, s_rew), (d_ter, s_ter) = self.reward, self.terminated
        (d_tru, s_tru), (d_term, s_term) = self.truncated, self.term
        return _step_dict(
            r,
            {
                kf: nd(sf, df, o.features.data),
                ka: nd(sa, da, o.adjacency.data),
                km: nd(sm, dm, o.mask.data),
                kn: nd(sn, dn, o.node_ids.data),
            },
            nd(s_rew, d_rew, r.reward.data),
            {k: nd(s_term, d_term, v.data) for k, v in r.reward_terms.items()},
            nd(s_ter, d_ter, r.terminated.data),
            nd(s_tru, d_tru, r.truncated.data),
        )


#: Layout decoders by layout: envs of one shape share one.
_STEP_LAYOUTS: dict[_Layout, _StepLayout] = {}


def step_decoder_for(res: Mapping[str, Any]):
    """The fastest decoder of the step replies of the env that gave ``res`` (a decoded
    ``StepResult``): a :class:`_StepLayout` of its array layout, or :func:`decode_step_result`
    when the result has none to fix (no observation, terms of several shapes)."""
    try:
        layout = _layout_of(res)
    except (KeyError, TypeError, AttributeError, ValueError):
        return decode_step_result
    decoder = _STEP_LAYOUTS.get(layout)
    if decoder is None:
        if len(_STEP_LAYOUTS) >= 256:
            _STEP_LAYOUTS.clear()
        decoder = _STEP_LAYOUTS[layout] = _StepLayout(layout)
    return decoder


class SimClient:
    """A trainer's connection to the sharedspace servers under ``prefix``.

    Args:
        endpoint, prefix, mode, listen, multicast, timeout, client_id, config: see
            :class:`~sharedspace.transport.Transport` (ignored when ``transport`` is given).
        transport: an existing transport to share.
        server_id: pin every ``create`` to this server (default: least loaded at each create).
        discover_timeout: how long ``create`` waits for a server to answer (default: timeout).
    """

    def __init__(
        self,
        endpoint: str | Sequence[str] | None = DEFAULT_ENDPOINT,
        prefix: str = DEFAULT_PREFIX,
        *,
        mode: str = "peer",
        listen: str | Sequence[str] | None = None,
        multicast: bool = False,
        timeout: float = DEFAULT_TIMEOUT,
        client_id: str | None = None,
        config: dict[str, Any] | None = None,
        transport: Transport | None = None,
        server_id: str | None = None,
        discover_timeout: float | None = None,
        protocol_version: int = codec.PROTOCOL_VERSION,
    ):
        self._own_transport = transport is None
        self.transport = transport or Transport(
            endpoint,
            prefix,
            mode=mode,
            listen=listen,
            multicast=multicast,
            timeout=timeout,
            client_id=client_id,
            config=config,
            protocol_version=protocol_version,
        )
        self.server_id = server_id
        self.discover_timeout = (
            self.transport.timeout if discover_timeout is None else float(discover_timeout)
        )
        #: env id -> server id of every env created (and not closed) by this client.
        self.env_server: dict[str, str] = {}
        #: env id -> ``n_ext`` (number of external agents).
        self.env_n_ext: dict[str, int] = {}
        self._closed_envs: set[str] = set()
        #: env id -> (server id, step key, request head, action shape, reply decoder) of envs
        #: stepped before.
        self._step_keys: dict[str, tuple[str, str, bytes, tuple[int, int], Any]] = {}
        self._step_heads: dict[int, bytes] = {}

    @property
    def client_id(self) -> str:
        return self.transport.client_id

    @property
    def timeout(self) -> float:
        return self.transport.timeout

    # ----------------------------------------------------------------------------------------

    def servers(self, timeout: float | None = None) -> list[dict[str, Any]]:
        """``ServerInfo`` of every live server, least loaded first."""
        return self.transport.servers(timeout if timeout is not None else self.discover_timeout)

    def info(self, server_id: str) -> dict[str, Any]:
        """``ServerInfo`` of one server."""
        return self._request(
            server_id,
            self.transport.key("server", server_id, "info"),
            codec.encode_info_request(self.transport.protocol_version),
        )

    def pick_server(self, exclude: Sequence[str] = (), need: int = 1) -> dict[str, Any]:
        return self.transport.pick_server(exclude, timeout=self.discover_timeout, need=need)

    def pools(self, server_id: str | None = None) -> list[dict[str, Any]]:
        """The scenario pools a server serves (``ServerInfo.pools``: name, split sizes and every
        scenario's name and split in pool order); the least-loaded server's by default."""
        info = self.info(server_id) if server_id else self.pick_server()
        return list(info.get("pools", []))

    def scenarios(
        self, pool: str | None = None, server_id: str | None = None
    ) -> tuple[str, list[tuple[str, str]]]:
        """``(pool name, [(scenario name, split), ...])`` in pool order, as the server serves
        them (``pool`` None: the server's default pool). A scenario's position in the list is
        its ``scenario_index``; its name is what ``Reset``/``CreateEnv`` take."""
        pools = self.pools(server_id)
        chosen = pools[0] if pool is None and pools else None
        for p in pools:
            if p["name"] == pool:
                chosen = p
        if chosen is None:
            names = [p["name"] for p in pools]
            raise SharedspaceError(f"no scenario pool {pool!r} on the server (pools: {names})")
        return str(chosen["name"]), [
            (str(sc["name"]), str(sc["split"])) for sc in chosen.get("scenarios", [])
        ]

    def _server_of(self, env_id: str) -> str:
        sid = self.env_server.get(env_id)
        if sid is None:
            if env_id in self._closed_envs:
                raise EnvClosed("env_closed", f"env {env_id!r} was closed by this client", env_id)
            raise SharedspaceError(f"env {env_id!r} was not created by this client")
        return sid

    def _lost(self, server_id: str, reason: str) -> ServerLost:
        envs = [e for e, s in self.env_server.items() if s == server_id]
        return ServerLost(server_id, reason, envs)

    def _check_alive(self, server_id: str) -> None:
        # Liveliness read at most _ALIVE_MAX_AGE ago is fresh enough here: a request to a
        # server that is gone fails anyway, and the failure path reads it afresh.
        if not self.transport.is_alive(server_id, max_age=_ALIVE_MAX_AGE):
            raise self._lost(server_id, "its liveliness token disappeared")

    def _request(
        self,
        server_id: str,
        key: str,
        payload: bytes,
        timeout: float | None = None,
        decode=decode_result,
    ):
        transport = self.transport
        if transport.closed:
            raise SharedspaceError("the client is closed")
        try:
            pending = transport.get_async(key, payload, timeout)
            # Checked while the server works on the query rather than before sending it: the
            # check costs some microseconds, and a query to a server that is gone is harmless.
            self._check_alive(server_id)
            return decode(transport.wait(pending))
        except QueryFailed as e:
            if not self.transport.is_alive(server_id):
                raise self._lost(server_id, "its liveliness token disappeared") from e
            raise self._lost(server_id, str(e)) from e

    def _request_many(self, server_id: str, calls: Sequence[tuple[str, bytes]]) -> list[Any]:
        """Several queries to one server in flight at once; replies in order."""
        self._check_alive(server_id)
        pending = [self.transport.get_async(k, p) for k, p in calls]
        out = []
        first_err: BaseException | None = None
        for p in pending:
            try:
                out.append(decode_result(self.transport.wait(p)))
            except QueryFailed as e:
                reason = (
                    "its liveliness token disappeared"
                    if not self.transport.is_alive(server_id)
                    else str(e)
                )
                first_err = first_err or self._lost(server_id, reason)
            except SharedspaceError as e:
                first_err = first_err or e
        if first_err is not None:
            raise first_err
        return out

    # ----------------------------------------------------------------------------------------
    # Requests

    def create(
        self, count: int = 1, *, server_id: str | None = None, **params: Any
    ) -> dict[str, Any]:
        """``CreateEnv`` of ``count`` envs (SPEC 5.2; ``params`` are its fields: ``seed``,
        ``split``, ``pool``, ``pedestrian_model``, ``external_agents``, ``max_agents``,
        ``autoreset``, ...) on ``server_id`` or the least-loaded server. Returns ``EnvCreated``
        with ``server_id`` added."""
        params = dict(params)
        version = int(params.pop("protocol_version", self.transport.protocol_version))
        sid = server_id or self.server_id
        if sid is None:
            sid = str(self.pick_server(need=int(count))["server_id"])
        msg = codec.create_env(self.client_id, count=count, protocol_version=version, **params)
        try:
            created = self._request(
                sid,
                self.transport.key("server", sid, "env", "create"),
                codec.encode(msg),
                max(self.timeout, CREATE_TIMEOUT),
            )
        except ServerLost as e:
            if sid in self.transport.alive_servers():
                raise
            raise NoServer(
                self.transport.endpoint,
                max(self.timeout, CREATE_TIMEOUT),
                f"server {sid!r} (prefix {self.transport.prefix!r}) did not answer env/create "
                f"on {self.transport.endpoint!r}: {e.reason}",
            ) from e
        created["server_id"] = sid
        n_ext = len(created.get("external_agents") or msg["external_agents"])
        for env_id in created["env_ids"]:
            self.env_server[env_id] = sid
            self.env_n_ext[env_id] = n_ext
        return created

    def reset(
        self,
        env_id: str,
        seed: int | None = None,
        scenario: str | None = None,
        variation: int | None = None,
    ) -> dict[str, Any]:
        """``Reset`` (SPEC 5.3) → ``ResetResult``; ``variation``: play the scene variation of
        this seed (an env with variations)."""
        sid = self._server_of(env_id)
        return self._request(
            sid,
            self.transport.key("server", sid, "env", env_id, "reset"),
            codec.encode_reset(seed, scenario, variation),
        )

    def reset_many(
        self,
        env_ids: Sequence[str],
        seeds: Sequence[int | None] | None = None,
        scenarios: Sequence[str | None] | None = None,
        variations: Sequence[int | None] | None = None,
    ) -> list[dict[str, Any]]:
        """``Reset`` of several envs of one server, all queries in flight at once
        (``variations``: per env, the variation seed to play, or None for the env's draw)."""
        if not env_ids:
            return []
        sid = self._server_of(env_ids[0])
        calls = []
        for i, env_id in enumerate(env_ids):
            if self._server_of(env_id) != sid:
                raise ValueError("reset_many: every env must live on the same server")
            seed = None if seeds is None else seeds[i]
            scen = None if scenarios is None else scenarios[i]
            var = None if variations is None else variations[i]
            calls.append(
                (
                    self.transport.key("server", sid, "env", env_id, "reset"),
                    codec.encode_reset(seed, scen, var),
                )
            )
        return self._request_many(sid, calls)

    def step(self, env_id: str, actions: Any) -> dict[str, Any]:
        """``Step`` (SPEC 5.4): ``actions`` ``[n_ext, 2]`` (float32/64) → ``StepResult``."""
        fast = self._step_keys.get(env_id)
        if (
            fast is not None
            and type(actions) is np.ndarray
            and actions.dtype == _F4
            and actions.shape == fast[3]
        ):
            # The common case (a float32 array of the right shape, an env stepped before): one
            # lookup, no conversion; a step's client work is a share of its round trip.
            sid, key, head, _, decode = fast
            return self._request(sid, key, head + actions.tobytes(), decode=decode)
        sid = self._server_of(env_id)
        n_ext = self.env_n_ext.get(env_id)
        arr = np.asarray(actions, dtype="<f4")
        if arr.ndim == 1 and n_ext == 1:
            arr = arr.reshape(1, -1)
        if arr.shape != (n_ext, 2):
            raise WrongShape(
                message=f"step: actions of env {env_id} must have shape [{n_ext}, 2] "
                f"(n_ext, [acc, omega]), got {list(arr.shape)}",
                env_id=env_id,
            )
        head = self._step_heads.get(n_ext)
        if head is None:
            head = self._step_heads[n_ext] = codec.step_head(n_ext)
        key = self.transport.key("server", sid, "env", env_id, "step")
        res = self._request(sid, key, head + arr.tobytes(), decode=decode_step_result)
        # Later steps of this env take the fast path above, with a decoder of this layout.
        self._step_keys[env_id] = (sid, key, head, (n_ext, 2), step_decoder_for(res))
        return res

    def batch_step(
        self, env_ids: Sequence[str], actions: Any, timeout: float | None = None
    ) -> dict[str, Any]:
        """``BatchStep`` (SPEC 5.5): ``actions`` ``[K, n_ext, 2]`` → ``BatchStepResult``."""
        env_ids = list(env_ids)
        if not env_ids:
            raise ValueError("batch_step needs at least one env")
        sid = self._server_of(env_ids[0])
        n_ext = self.env_n_ext.get(env_ids[0])
        arr = np.asarray(actions, dtype=np.float32)
        want = (len(env_ids), n_ext, 2)
        if arr.shape != want:
            raise WrongShape(
                message=f"batch_step: actions must have shape [K={want[0]}, n_ext={n_ext}, 2], "
                f"got {list(arr.shape)}",
            )
        for env_id in env_ids:
            if self._server_of(env_id) != sid:
                raise ValueError("batch_step: every env must live on the same server")
        return self._request(
            sid,
            self.transport.key("server", sid, "batch", "step"),
            codec.encode({"env_ids": env_ids, "actions": arr}),
            timeout,
        )

    def close(self, env_id: str) -> dict[str, Any]:
        """``Close`` (SPEC 5.6)."""
        sid = self._server_of(env_id)
        try:
            return self._request(
                sid,
                self.transport.key("server", sid, "env", env_id, "close"),
                codec.encode_close(),
            )
        finally:
            self.forget(env_id)

    def close_many(self, env_ids: Sequence[str]) -> None:
        """Closes envs, all queries in flight at once; errors (already closed, server gone) are
        ignored."""
        by_server: dict[str, list[str]] = {}
        for e in env_ids:
            sid = self.env_server.get(e)
            if sid is not None:
                by_server.setdefault(sid, []).append(e)
        for sid, ids in by_server.items():
            if self.transport.closed or not self.transport.is_alive(sid):
                pass
            else:
                pending = [
                    self.transport.get_async(
                        self.transport.key("server", sid, "env", e, "close"),
                        codec.encode_close(),
                        min(self.timeout, 2.0),
                    )
                    for e in ids
                ]
                for p in pending:
                    try:
                        Transport.wait(p)
                    except SharedspaceError:
                        pass
            for e in ids:
                self.forget(e)

    def forget(self, env_id: str) -> None:
        """Drops an env from the client's books (it is closed or its server is gone)."""
        self.env_server.pop(env_id, None)
        self.env_n_ext.pop(env_id, None)
        self._step_keys.pop(env_id, None)
        self._closed_envs.add(env_id)

    def vector(self, num_envs: int, **params: Any) -> VectorClient:
        """A :class:`VectorClient` of ``num_envs`` envs on this connection."""
        return VectorClient(num_envs, client=self, **params)

    def shutdown(self) -> None:
        """Closes every env of this client and the transport (if this client opened it)."""
        if not self.transport.closed:
            self.close_many(list(self.env_server))
        if self._own_transport:
            self.transport.close()

    def __enter__(self) -> SimClient:
        return self

    def __exit__(self, *exc) -> None:
        self.shutdown()


def _stack_reset_obs(results: Sequence[Mapping[str, Any]]) -> dict[str, np.ndarray]:
    return {
        key: np.stack([r["obs"][key] for r in results])
        for key in ("features", "adjacency", "mask", "node_ids")
    }


class VectorClient:
    """K envs created by one ``CreateEnv``, stepped with one ``BatchStep`` per step.

    Args:
        num_envs: K.
        client: the :class:`SimClient` to use (default: a new one from ``endpoint`` etc.).
        failover: on :class:`ServerLost`, re-create the envs on a surviving server inside
            ``step``/``reset`` (see the module docstring) instead of raising.
        step_timeout: timeout of a ``BatchStep`` (default: the client's timeout).
        **params: ``CreateEnv`` fields (``seed``, ``split``, ``pool``, ``pedestrian_model``,
            ``external_agents``, ``max_agents``, ``autoreset``, ``scenario``, ...) and, when
            ``client`` is None, the :class:`SimClient` arguments ``endpoint``, ``prefix``,
            ``timeout``, ``mode``, ``listen``, ``multicast``, ``server_id``.
    """

    _CLIENT_KEYS = (
        "endpoint",
        "prefix",
        "timeout",
        "mode",
        "listen",
        "multicast",
        "client_id",
        "config",
        "server_id",
        "discover_timeout",
    )

    def __init__(
        self,
        num_envs: int,
        *,
        client: SimClient | None = None,
        failover: bool = False,
        step_timeout: float | None = None,
        **params: Any,
    ):
        if num_envs < 1:
            raise ValueError("num_envs must be at least 1")
        client_kwargs = {k: params.pop(k) for k in self._CLIENT_KEYS if k in params}
        self._own_client = client is None
        self.client = client or SimClient(**client_kwargs)
        self.num_envs = int(num_envs)
        self.params = params
        self.failover = bool(failover)
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
        self.created = self.client.create(self.num_envs, server_id=sid, **self.params)
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
        self._batch_head = codec.batch_step_head(self.env_ids) + codec.f32_array_head(
            (self.num_envs, self.n_ext, 2)
        )
        known = (codec.encode(list(self.env_ids)), list(self.env_ids))
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
            res = self.client._request(
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
            obs = {k: np.array(res["obs"][k]) for k in _OBS_KEYS}
            resets = res["resets"]
            if len(resets["index"]):
                for key in _OBS_KEYS:
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

    def __enter__(self) -> VectorClient:
        return self

    def __exit__(self, *exc) -> None:
        self.close()


def wait_until(pred, timeout: float, interval: float = 0.02) -> bool:
    """Polls ``pred`` until it is true or ``timeout`` passes (test and example helper)."""
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        if pred():
            return True
        time.sleep(interval)
    return bool(pred())
