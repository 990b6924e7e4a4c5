"""The wire's envelope and arrays (protocol/SPEC.md sections 2-4; the protocol crate's
``array.rs``, ``codec.rs`` and ``messages/envelope.rs``).

Messages are plain dicts keyed by field name. Binary arrays (``{dtype, shape, data}`` maps with
``data`` as MessagePack ``bin``) decode to read-only numpy arrays that view the decoded bytes
(``np.frombuffer``, no copy) and numpy arrays encode back to such maps, so
``encode(decode(payload)) == payload`` for every message the server writes. A reply is the
envelope ``{"ok": result}`` or ``{"error": {code, message, env_id}}``: :func:`unwrap_reply` gives
the result or raises the typed :class:`~sharedspace.wire.errors.ServerError`.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any

import msgspec
import numpy as np

from .errors import ProtocolError, server_error

__all__ = [
    "PROTOCOL_VERSION",
    "ARRAY_DTYPES",
    "PADDING_ID",
    "encode",
    "decode",
    "encode_array",
    "decode_array",
    "f32_array_head",
    "is_array_map",
    "ok",
    "error",
    "unwrap_reply",
]

PROTOCOL_VERSION = 2

#: dtype strings allowed in binary arrays, with their item size.
ARRAY_DTYPES: dict[str, int] = {"<f4": 4, "<f8": 8, "<u4": 4, "<u8": 8, "|u1": 1}

#: ``node_ids`` value of padding nodes.
PADDING_ID = 0xFFFFFFFF

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


def f32_array_head(shape: Sequence[int]) -> bytes:
    """The bytes of a float32 binary-array map of ``shape`` before its data:
    ``f32_array_head(a.shape) + a.tobytes()`` equals ``encode(encode_array(a))`` for a
    C-contiguous little-endian float32 array ``a``."""
    shape = [int(d) for d in shape]
    n = 4 * int(np.prod(shape, dtype=np.int64))
    full = encode({"dtype": "<f4", "shape": shape, "data": bytes(n)})
    return full[:-n] if n else full


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
#: :mod:`sharedspace.wire.replies`.
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
