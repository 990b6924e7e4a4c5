"""MessagePack codec of the sharedspace wire protocol, version 2 (protocol/SPEC.md).

Messages are plain dicts keyed by field name. Binary arrays (``{dtype, shape, data}`` maps with
``data`` as MessagePack ``bin``) decode to read-only numpy arrays that view the decoded bytes
(``np.frombuffer``, no copy) and numpy arrays encode back to such maps, so
``encode(decode(payload)) == payload`` for every message the server writes.

Request builders (:func:`info_request`, :func:`create_env`, :func:`reset`, :func:`step`,
:func:`batch_step`, :func:`close`, :func:`action_msg`) return the message dict with every field
in wire order; ``encode_*`` variants return the bytes. :func:`decode_reply` unwraps the reply
envelope and raises the typed :class:`~sharedspace.errors.ServerError` subclass on an error.
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping, Sequence
from typing import Any

import msgspec
import numpy as np

from . import names as _names
from .errors import (
    ProtocolError,
    ServerError,
    SharedspaceError,
    WrongShape,
    server_error,
)
from .models import DEFAULT_MODEL

__all__ = [
    "PROTOCOL_VERSION",
    "ARRAY_DTYPES",
    "PADDING_ID",
    "FEATURE_NAMES",
    "encode",
    "decode",
    "decode_reply",
    "encode_array",
    "decode_array",
    "is_array_map",
    "ok",
    "error",
    "info_request",
    "create_env",
    "reset",
    "step",
    "batch_step",
    "close",
    "action_msg",
    "encode_info_request",
    "encode_create_env",
    "encode_reset",
    "encode_step",
    "encode_batch_step",
    "step_head",
    "batch_step_head",
    "encode_close",
    "encode_action_msg",
    "SharedspaceError",
    "ServerError",
    "ProtocolError",
]

PROTOCOL_VERSION = 2

#: dtype strings allowed in binary arrays, with their item size.
ARRAY_DTYPES: dict[str, int] = {"<f4": 4, "<f8": 8, "<u4": 4, "<u8": 8, "|u1": 1}

#: ``node_ids`` value of padding nodes.
PADDING_ID = 0xFFFFFFFF

#: Node features of an observation, in order (SPEC.md section 7; :mod:`sharedspace.names`).
FEATURE_NAMES = _names.FEATURE_NAMES

_ARRAY_KEYS = frozenset(("dtype", "shape", "data"))


# --------------------------------------------------------------------------------------------
# Binary arrays


def is_array_map(m: Any) -> bool:
    """Whether ``m`` is a binary-array map ``{dtype, shape, data: bin}``."""
    return (
        isinstance(m, dict)
        and _ARRAY_KEYS.issubset(m.keys())
        and isinstance(m["data"], bytes | bytearray | memoryview)
        and isinstance(m["dtype"], str)
    )


def decode_array(m: Mapping[str, Any]) -> np.ndarray:
    """A binary-array map as a numpy array viewing ``m["data"]`` (read-only, no copy)."""
    dtype = m["dtype"]
    if dtype not in ARRAY_DTYPES:
        raise ProtocolError(
            f"binary array: unsupported dtype {dtype!r} (allowed {list(ARRAY_DTYPES)})"
        )
    shape = m["shape"]
    if not isinstance(shape, list | tuple) or not all(
        isinstance(s, int) and not isinstance(s, bool) and s >= 0 for s in shape
    ):
        raise ProtocolError(
            f"binary array: shape must be a list of non-negative integers, got {shape!r}"
        )
    data = m["data"]
    count = 1
    for s in shape:
        count *= s
    want = count * ARRAY_DTYPES[dtype]
    if len(data) != want:
        raise ProtocolError(
            f"binary array: data has {len(data)} bytes, shape {list(shape)} of {dtype} needs {want}"
        )
    return np.frombuffer(data, dtype=np.dtype(dtype)).reshape(tuple(shape))


def encode_array(a: Any, dtype: str | None = None) -> dict[str, Any]:
    """A numpy array (or array-like) as a binary-array map, C order, little-endian.

    ``dtype`` forces one of :data:`ARRAY_DTYPES`; otherwise the array's own dtype must be one of
    them (``bool`` is sent as ``|u1``).
    """
    arr = np.asarray(a)
    if dtype is not None:
        if dtype not in ARRAY_DTYPES:
            raise ValueError(f"dtype {dtype!r} is not a wire dtype ({list(ARRAY_DTYPES)})")
        arr = arr.astype(np.dtype(dtype), copy=False)
    elif arr.dtype == np.bool_:
        arr = arr.astype(np.uint8)
    else:
        wire = arr.dtype.newbyteorder("<").str if arr.dtype.byteorder == ">" else arr.dtype.str
        if wire not in ARRAY_DTYPES:
            raise ValueError(f"array dtype {arr.dtype} has no wire form ({list(ARRAY_DTYPES)})")
        arr = arr.astype(np.dtype(wire), copy=False)
    return {
        "dtype": arr.dtype.str,
        "shape": [int(s) for s in arr.shape],
        "data": np.ascontiguousarray(arr).tobytes(),
    }


# --------------------------------------------------------------------------------------------
# Generic encode / decode


def _prepare(v: Any) -> Any:
    if isinstance(v, np.ndarray):
        return encode_array(v)
    if isinstance(v, dict):
        return {k: _prepare(x) for k, x in v.items()}
    if isinstance(v, list | tuple):
        return [_prepare(x) for x in v]
    if isinstance(v, np.bool_):
        return bool(v)
    if isinstance(v, np.integer):
        return int(v)
    if isinstance(v, np.floating):
        return float(v)
    return v


def encode(message: Any) -> bytes:
    """One message as MessagePack bytes (named maps; numpy arrays become binary-array maps)."""
    return _ENCODER.encode(_prepare(message))


#: The package's one MessagePack library (msgspec): untyped here, typed per reply shape in
#: :mod:`sharedspace.decode`.
_ENCODER = msgspec.msgpack.Encoder()
_DECODER = msgspec.msgpack.Decoder()


def _arrays_in(v: Any) -> Any:
    """``v`` with every binary-array map (at any depth) a numpy array."""
    if type(v) is dict:
        if is_array_map(v):
            return decode_array(v)
        for k, x in v.items():
            if type(x) is dict or type(x) is list:
                v[k] = _arrays_in(x)
    elif type(v) is list:
        for i, x in enumerate(v):
            if type(x) is dict or type(x) is list:
                v[i] = _arrays_in(x)
    return v


def decode(payload: bytes | bytearray | memoryview, *, arrays: bool = True) -> Any:
    """Decodes one message. Binary arrays become numpy arrays unless ``arrays`` is false.

    An empty payload decodes as ``{}`` (the spec accepts it for InfoRequest, Reset and Close).
    """
    if len(payload) == 0:
        return {}
    try:
        message = _DECODER.decode(payload)
    except msgspec.DecodeError as e:  # truncated, trailing bytes, malformed
        raise ProtocolError(f"undecodable payload: {type(e).__name__}: {e}") from e
    return _arrays_in(message) if arrays else message


# --------------------------------------------------------------------------------------------
# Reply envelope


def ok(result: Any) -> dict[str, Any]:
    """The success envelope ``{"ok": result}``."""
    return {"ok": result}


def error(code: str, message: str, env_id: str | None = None) -> dict[str, Any]:
    """The error envelope ``{"error": {code, message, env_id}}``."""
    return {"error": {"code": code, "message": message, "env_id": env_id}}


def unwrap_reply(reply: Any) -> Any:
    """The ``ok`` value of a decoded reply envelope; raises the typed ServerError on ``error``."""
    if not isinstance(reply, dict):
        raise ProtocolError(f"reply envelope must be a map, got {type(reply).__name__}")
    has_ok = "ok" in reply
    has_err = "error" in reply
    if has_ok == has_err:
        raise ProtocolError(
            "reply envelope must have exactly one of `ok` and `error`, "
            f"got keys {sorted(map(str, reply))}"
        )
    if has_ok:
        return reply["ok"]
    err = reply["error"]
    if not isinstance(err, dict) or "code" not in err or "message" not in err:
        raise ProtocolError(f"malformed error reply: {err!r}")
    raise server_error(str(err["code"]), str(err["message"]), err.get("env_id"))


def decode_reply(payload: bytes | bytearray | memoryview) -> Any:
    """Decodes a reply and returns its ``ok`` value, or raises its error (see :mod:`.errors`):
    :func:`sharedspace.decode.decode_result`, the one reply decoder."""
    from .decode import decode_result  # it builds on this module

    return decode_result(bytes(payload))


# --------------------------------------------------------------------------------------------
# Requests (SPEC.md section 5), every field in wire order.


def info_request(protocol_version: int | None = PROTOCOL_VERSION) -> dict[str, Any]:
    return {"protocol_version": protocol_version}


def create_env(
    client_id: str,
    *,
    count: int = 1,
    pool: str | None = None,
    split: str = "train",
    seed: int = 0,
    pedestrian_model: str = DEFAULT_MODEL,
    pedestrian_params: Mapping[str, float] | None = None,
    external_agents: Sequence[str] = ("vehicle_0",),
    reward_weights: Mapping[str, float] | None = None,
    mode: str = "lockstep",
    max_agents: int = 8,
    scenario: str | None = None,
    autoreset: bool = False,
    realtime_factor: float = 1.0,
    protocol_version: int = PROTOCOL_VERSION,
    synthetic: Mapping[str, Any] | None = None,
    variations: Mapping[str, Any] | None = None,
    vehicle_model: str | None = None,
) -> dict[str, Any]:
    """``CreateEnv`` (SPEC 5.2). ``synthetic``: generated scenes instead of a pool, a map of
    ``layout`` (``crossing``, ``counter_flow``, ``random``), ``pedestrians``, ``vehicles``,
    ``density``, ``seed``, ``scenes`` (defaults in SPEC 5.2). ``variations``: seeded scene
    variations, a map of ``position_sigma``, ``start_offset_steps``, ``desired_speed_scale``,
    ``param_noise``, ``mirror``, ``rotation_deg`` (SPEC 5.2.1; the server checks them).
    ``vehicle_model``: how the cars nobody controls move, ``replay`` or ``idm`` (None: the
    pool's; docs/MODEL.md "Traffic")."""
    if split not in ("train", "test"):
        raise ValueError(f"split must be 'train' or 'test', got {split!r}")
    if mode not in ("lockstep", "realtime"):
        raise ValueError(f"mode must be 'lockstep' or 'realtime', got {mode!r}")
    return (
        {
            "protocol_version": int(protocol_version),
            "client_id": client_id,
            "count": int(count),
            "pool": pool,
            "split": split,
            "seed": int(seed),
            "pedestrian_model": pedestrian_model,
            "pedestrian_params": {k: float(v) for k, v in (pedestrian_params or {}).items()},
            "external_agents": list(external_agents),
            "reward_weights": {k: float(v) for k, v in (reward_weights or {}).items()},
            "mode": mode,
            "max_agents": int(max_agents),
            "scenario": scenario,
            "autoreset": bool(autoreset),
            "realtime_factor": float(realtime_factor),
        }
        | ({"synthetic": dict(synthetic)} if synthetic is not None else {})
        | ({"variations": dict(variations)} if variations is not None else {})
        | ({"vehicle_model": vehicle_model} if vehicle_model is not None else {})
    )


def reset(
    seed: int | None = None, scenario: str | None = None, variation: int | None = None
) -> dict[str, Any]:
    """``Reset`` (SPEC 5.3); ``variation``: the seed of the scene variation to play."""
    out: dict[str, Any] = {"seed": None if seed is None else int(seed), "scenario": scenario}
    if variation is not None:
        out["variation"] = int(variation)
    return out


def _action_array(actions: Any, shape_tail: tuple[int, ...], what: str) -> np.ndarray:
    arr = np.asarray(actions)
    if arr.dtype not in (np.float32, np.float64):
        arr = arr.astype(np.float64)
    if arr.dtype.byteorder == ">":
        arr = arr.astype(arr.dtype.newbyteorder("<"))
    if arr.ndim != len(shape_tail) or any(
        want is not None and got != want for got, want in zip(arr.shape, shape_tail, strict=True)
    ):
        want = "[" + ", ".join("?" if w is None else str(w) for w in shape_tail) + "]"
        raise WrongShape(message=f"{what}: actions must have shape {want}, got {list(arr.shape)}")
    return arr


def step(actions: Any, n_ext: int | None = None) -> dict[str, Any]:
    """``Step``: ``actions`` of shape ``[n_ext, 2]`` (a single ``[2]`` action is taken as
    ``[1, 2]``); float32 and float64 are sent as they are, anything else as float64."""
    arr = np.asarray(actions)
    if arr.ndim == 1:
        arr = arr.reshape(1, -1)
    return {"actions": _action_array(arr, (n_ext, 2), "Step")}


def batch_step(env_ids: Iterable[str], actions: Any, n_ext: int | None = None) -> dict[str, Any]:
    """``BatchStep``: ``actions`` of shape ``[K, n_ext, 2]``, K = ``len(env_ids)``."""
    ids = list(env_ids)
    arr = _action_array(actions, (len(ids), n_ext, 2), "BatchStep")
    return {"env_ids": ids, "actions": arr}


def close() -> dict[str, Any]:
    return {}


def action_msg(action: Any, seq: int = 0) -> dict[str, Any]:
    """Realtime ``ActionMsg`` (SPEC.md 5.7): ``action`` of shape ``[2]``."""
    return {"action": _action_array(action, (2,), "ActionMsg"), "seq": int(seq)}


def encode_info_request(protocol_version: int | None = PROTOCOL_VERSION) -> bytes:
    return encode(info_request(protocol_version))


def encode_create_env(client_id: str, **kwargs: Any) -> bytes:
    return encode(create_env(client_id, **kwargs))


def encode_reset(
    seed: int | None = None, scenario: str | None = None, variation: int | None = None
) -> bytes:
    return encode(reset(seed, scenario, variation))


def encode_step(actions: Any, n_ext: int | None = None) -> bytes:
    return encode(step(actions, n_ext))


def encode_batch_step(env_ids: Iterable[str], actions: Any, n_ext: int | None = None) -> bytes:
    return encode(batch_step(env_ids, actions, n_ext))


def step_head(n_ext: int) -> bytes:
    """The bytes of a float32 ``Step`` of ``n_ext`` rows before its action data:
    ``step_head(n) + a.tobytes()`` equals ``encode_step(a)`` for a float32 ``[n, 2]`` array
    ``a`` (``data`` is the message's last field)."""
    n = int(n_ext)
    tail = 8 * n
    full = encode({"actions": {"dtype": "<f4", "shape": [n, 2], "data": bytes(tail)}})
    return full[:-tail] if tail else full


def f32_array_head(shape: Sequence[int]) -> bytes:
    """The bytes of a float32 binary-array map of ``shape`` before its data:
    ``f32_array_head(a.shape) + a.tobytes()`` equals ``encode(encode_array(a))`` for a
    C-contiguous little-endian float32 array ``a``."""
    shape = [int(d) for d in shape]
    n = 4 * int(np.prod(shape, dtype=np.int64))
    full = encode({"dtype": "<f4", "shape": shape, "data": bytes(n)})
    return full[:-n] if n else full


def batch_step_head(env_ids: Iterable[str]) -> bytes:
    """The bytes of a ``BatchStep`` before its actions array: a trainer stepping the same K envs
    again and again encodes them once; ``batch_step_head(ids) + encode(encode_array(a))`` equals
    ``encode_batch_step(ids, a)`` for a float32 array ``a``."""
    return b"\x82" + encode("env_ids") + encode(list(env_ids)) + encode("actions")


def encode_close() -> bytes:
    return encode(close())


def encode_action_msg(action: Any, seq: int = 0) -> bytes:
    return encode(action_msg(action, seq))
