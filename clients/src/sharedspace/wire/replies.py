"""The server's replies as numpy (protocol/SPEC.md sections 5 and 6; the protocol crate's
``messages/replies.rs``): one msgspec decoder per reply shape, arrays as zero-copy numpy views of
the payload (``_view``).

- :func:`decode_result`: any reply's ``result`` (generic: maps, lists, arrays as numpy), the
  one decoder every other falls back to for errors and anything off its schema;
- :func:`decode_step_result` / :func:`step_decoder_for`: a ``StepResult`` (the per-env hot
  path; the layout-specialised decoder of an env is built once from its first reply);
- :func:`decode_batch_result`: a ``BatchStepResult`` (the batched hot path).
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Annotated, Any, Literal

import msgspec
import numpy as np

from .. import names
from . import envelope
from .errors import ProtocolError

REWARD_TERMS = names.REWARD_TERMS

#: The arrays of an observation.
OBS_KEYS = ("features", "adjacency", "mask", "node_ids")
#: The dtype of every float32 array on the wire.
F4 = np.dtype("<f4")
_RESULT_ARRAYS = ("reward", "terminated", "truncated")
#: The per-env columns of a ``BatchStepResult``, and of its stacked ``resets``.
_BATCH_COLUMNS = ("episode", "step", "t", "action_clipped")
_RESET_COLUMNS = ("index", "episode", "horizon_steps")
#: Wire dtype -> (numpy dtype, item size), resolved once: ``np.dtype("<f4")`` per array is a
#: measurable share of decoding a small step reply.
_WIRE_DTYPES = {name: (np.dtype(name), size) for name, size in envelope.ARRAY_DTYPES.items()}


def _array(m: Any) -> np.ndarray:
    """A binary-array map as a read-only numpy view (lean twin of ``envelope.decode_array``,
    which it falls back to for anything unusual so that errors stay precise)."""
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
    if not envelope.is_array_map(m):
        raise ProtocolError(f"expected a binary-array map {{dtype, shape, data}}, got {m!r:.80}")
    return envelope.decode_array(m)


def _obs_in(r: Any) -> None:
    if type(r) is dict:
        obs = r.get("obs")
        if type(obs) is dict:
            for k in OBS_KEYS:
                if k in obs:
                    obs[k] = _array(obs[k])


#: Untyped MessagePack decoder of replies: dicts, lists, str and bytes, as fast as a decoder
#: without a per-map hook gets (a K = 256 batch reply: 0.93 ms where msgpack-python's
#: ``unpackb`` took 1.31; docs/BENCHMARKS.md section 3, in its git history).
_REPLY_DECODER = msgspec.msgpack.Decoder()


def decode_result(payload: bytes) -> Any:
    """Decodes a reply envelope (``{"ok": result}``: the result; ``{"error": ...}``: raises the
    typed :class:`~sharedspace.wire.errors.ServerError`). MessagePack is decoded by msgspec
    without a per-map hook and only the binary arrays of ``ResetResult``/``StepResult``/
    ``BatchStepResult`` (``obs``, ``reward``, ``reward_terms``, ``terminated``, ``truncated``,
    the autoreset ``reset.obs``, a batch's per-env columns and its stacked ``resets``) become
    numpy views; any other map is left as it is (``ServerInfo``, ``EnvCreated`` and ``Closed``
    carry no arrays)."""
    if len(payload) == 0:
        raise ProtocolError("empty reply payload")
    try:
        msg = _REPLY_DECODER.decode(payload)
    except msgspec.DecodeError as e:  # truncated, trailing bytes, malformed
        raise ProtocolError(f"undecodable reply: {e}") from e
    r = envelope.unwrap_reply(msg)
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
        tuple((k, *spec(o[k])) for k in OBS_KEYS),
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
