"""The requests a client sends (protocol/SPEC.md section 5; the protocol crate's
``messages/requests.rs``), and :class:`EnvSpec`, the typed ``CreateEnv`` every env is made from.

:class:`EnvSpec` holds the fields of ``CreateEnv`` that describe the envs (pool, split, seed,
crowd model, ...); the request adds who asks (``client_id``), how many (``count``) and the
protocol version (:func:`create_env`). It is built once, where the user writes it, and passed
whole from the env adapters to the wire: a misspelt field fails at construction
(``TypeError`` naming it), an ill-typed one too (``ValueError`` naming it and what it expected).
A new ``CreateEnv`` field is one line here and one in ``requests.rs``
(``clients/tests/test_codec.py`` checks that both hold the same fields, byte for byte).

The other builders (:func:`info_request`, :func:`reset`, :func:`step`, :func:`batch_step`,
:func:`close`, :func:`action_msg`) return the message dict with every field in wire order;
``encode_*`` variants return the bytes.
"""

from __future__ import annotations

from collections.abc import Iterable
from typing import Annotated, Any, Literal

import msgspec
import numpy as np

from ..models import DEFAULT_MODEL, PEDESTRIAN_MODELS, VEHICLE_MODELS
from .envelope import PROTOCOL_VERSION, encode
from .errors import WrongShape

__all__ = [
    "Checked",
    "EnvSpec",
    "SyntheticScenes",
    "ComposedScenes",
    "VariationSpec",
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
    "encode_close",
    "encode_action_msg",
    "step_head",
    "batch_step_head",
]

_NonNegative = Annotated[int, msgspec.Meta(ge=0)]


class Checked(msgspec.Struct, kw_only=True, forbid_unknown_fields=True):
    """A struct whose every field is checked against its type when it is made (msgspec checks
    types when it decodes, not in ``__init__``): the error names the field."""

    def __post_init__(self) -> None:
        for field in msgspec.structs.fields(self):
            value = getattr(self, field.name)
            try:
                checked = msgspec.convert(msgspec.to_builtins(value), field.type)
            except (msgspec.ValidationError, TypeError) as e:
                # msgspec says where inside the value: "Expected `int` >= 0 - at `$.seed`".
                what, _, where = str(e).partition(" - at `$")
                name = f"{type(self).__name__}.{field.name}{where.rstrip('`')}"
                raise ValueError(f"{name}: {what} (got {value!r})") from None
            setattr(self, field.name, checked)

    @classmethod
    def fields(cls) -> tuple[str, ...]:
        """The field names, in wire order."""
        return cls.__struct_fields__

    def replace(self, **changes: Any):
        """A copy with ``changes`` applied (checked like a new one)."""
        return type(self)(**{**msgspec.structs.asdict(self), **changes})

    def to_dict(self) -> dict[str, Any]:
        """The fields as plain Python values (nested structs as dicts)."""
        return msgspec.to_builtins(self)


class SyntheticScenes(Checked):
    """``CreateEnv.synthetic`` (SPEC 5.2): generated scenes instead of a pool's."""

    #: ``crossing``, ``counter_flow`` or ``random``: where the pedestrians walk.
    layout: Literal["crossing", "counter_flow", "random"] = "crossing"
    #: Pedestrians per scene.
    pedestrians: _NonNegative = 10
    #: Vehicles per scene (the ego first, the others by ``routes``).
    vehicles: Annotated[int, msgspec.Meta(ge=1)] = 1
    #: ``lanes``: parallel lanes 4 m apart, alternately oncoming. ``intersection``: at most 4
    #: vehicles heading +x, +y, -x, -y through a crossing at the square's centre, the others
    #: starting 0-2 s of driving behind the ego's start line (seeded), all from step 0.
    routes: Literal["lanes", "intersection"] = "lanes"
    #: Pedestrians per square metre of the crowd's square.
    density: float = 0.25
    #: Seed of the first scene (scene ``i`` has ``seed + i``).
    seed: _NonNegative = 0
    #: Number of scenes.
    scenes: Annotated[int, msgspec.Meta(ge=1)] = 1


class ComposedScenes(Checked):
    """``CreateEnv.composed`` (SPEC 5.2.2): scenes the server composes from the recorded parts
    of a pool's train scenes, scene ``i`` named ``composed-s{seed}-{i}``."""

    #: Composed scenes ``0..scenes`` drawn beside the split's recorded ones (each episode one of
    #: the ``recorded + scenes`` uniformly); None: a fresh composed scene every episode.
    scenes: Annotated[int, msgspec.Meta(ge=1)] | None = None
    #: The generator's seed.
    seed: _NonNegative = 0
    #: The served pool whose train scenes give the parts (None: the request's ``pool``).
    source: str | None = None
    #: Scenes of ``source`` whose agents never enter a composed scene (a validation split).
    hold_out: tuple[str, ...] = ()
    #: Pedestrians per scene (None: as many as the route's recorded scene had).
    pedestrians: _NonNegative | None = None
    #: Weights of the pedestrians' roles by name; a role not named keeps its recorded share.
    shares: dict[Literal["crossing", "along", "oncoming", "background"], float] = {}
    #: Whether the route's recorded other cars come along.
    other_cars: bool = True


class VariationSpec(Checked):
    """``CreateEnv.variations`` (SPEC 5.2.1, sim-core ``VariationSpec``): seeded scene
    variations, one drawn per episode. The server checks the ranges."""

    #: Standard deviation of each pedestrian's position offset, per axis, m.
    position_sigma: float = 0.0
    #: Each pedestrian's first step moves by up to this many steps either way.
    start_offset_steps: _NonNegative = 0
    #: Half-width ``s`` of each pedestrian's desired-speed factor, uniform in ``[1-s, 1+s]``.
    desired_speed_scale: float = 0.0
    #: Per social-force parameter, the half-width of its factor, drawn once per episode.
    param_noise: dict[str, float] = {}
    #: Mirror the scene about the ego's first heading in half of the episodes.
    mirror: bool = False
    #: Rotate the scene about the ego's first position by up to this many degrees.
    rotation_deg: float = 0.0


class EnvSpec(Checked):
    """What envs to make: the fields of ``CreateEnv`` (SPEC 5.2) but the request's own
    (``protocol_version``, ``client_id``, ``count``), in wire order, with the server's
    defaults. ``EnvSpec(pool="hbs-general", vehicle_model="idm")``; ``spec.replace(seed=3)``."""

    #: Scenario pool name (None: the server's default pool, the first it lists).
    pool: str | None = None
    #: Split the episodes are drawn from.
    split: Literal["train", "test"] = "train"
    #: Base seed; env k of one request uses ``seed + k``.
    seed: _NonNegative = 0
    #: Model of the simulated crowd (:data:`sharedspace.models.PEDESTRIAN_MODELS`).
    pedestrian_model: Literal[PEDESTRIAN_MODELS] = DEFAULT_MODEL  # type: ignore[valid-type]
    #: Pedestrian-model parameter overrides by name (docs/PARAMETERS.md).
    pedestrian_params: dict[str, float] = {}
    #: The vehicles the client drives, in action order (``vehicle_0``: the scenario's ego).
    external_agents: tuple[str, ...] = ("vehicle_0",)
    #: Reward weight overrides by name (docs/MODEL.md section 7).
    reward_weights: dict[str, float] = {}
    #: ``lockstep`` (the client steps) or ``realtime`` (the server's clock steps).
    mode: Literal["lockstep", "realtime"] = "lockstep"
    #: M, nodes per observation, ego included.
    max_agents: Annotated[int, msgspec.Meta(ge=1)] = 8
    #: Pin every episode to this scenario (None: drawn from the split).
    scenario: str | None = None
    #: The server resets an env when its episode ends (the step carries the new episode).
    autoreset: bool = False
    #: Realtime mode: simulated seconds per wall-clock second.
    realtime_factor: Annotated[float, msgspec.Meta(gt=0)] = 1.0
    #: Generated scenes instead of a pool's.
    synthetic: SyntheticScenes | None = None
    #: Scenarios of the split never drawn, by name (a validation split held out).
    exclude: tuple[str, ...] = ()
    #: Scenes composed from the recorded parts of a pool's train scenes.
    composed: ComposedScenes | None = None
    #: Seeded scene variations, one per episode (None: the pool's, if it has some).
    variations: VariationSpec | None = None
    #: How the cars nobody controls move (:data:`sharedspace.models.VEHICLE_MODELS`; None:
    #: the pool's).
    vehicle_model: Literal[VEHICLE_MODELS] | None = None  # type: ignore[valid-type]

    @classmethod
    def of(cls, spec: EnvSpec | None = None, **fields: Any) -> EnvSpec:
        """``spec`` (default: the defaults) with ``fields`` over it."""
        return (spec or cls()).replace(**fields) if fields else (spec or cls())


#: ``CreateEnv`` fields the server omits when nil (``skip_serializing_if``), as the client does.
_OMITTED_WHEN_NONE = ("synthetic", "composed", "variations", "vehicle_model")


# --------------------------------------------------------------------------------------------
# Requests (SPEC.md section 5), every field in wire order.


def info_request(protocol_version: int | None = PROTOCOL_VERSION) -> dict[str, Any]:
    return {"protocol_version": protocol_version}


def create_env(
    spec: EnvSpec, client_id: str, count: int = 1, protocol_version: int = PROTOCOL_VERSION
) -> dict[str, Any]:
    """``CreateEnv`` (SPEC 5.2) of ``count`` envs of ``spec`` for ``client_id``."""
    head = {"protocol_version": int(protocol_version), "client_id": client_id, "count": int(count)}
    fields = spec.to_dict()
    for key in _OMITTED_WHEN_NONE:
        if fields[key] is None:
            del fields[key]
    if not fields["exclude"]:  # omitted when empty, as the server does
        del fields["exclude"]
    return head | fields


def reset(
    seed: int | None = None, scenario: str | None = None, variation: int | None = None
) -> dict[str, Any]:
    """``Reset`` (SPEC 5.3); ``variation``: the seed of the scene variation to play."""
    out: dict[str, Any] = {"seed": None if seed is None else int(seed), "scenario": scenario}
    if variation is not None:
        out["variation"] = int(variation)
    return out


def _action_array(actions: Any, shape_tail: tuple[int | None, ...], what: str) -> np.ndarray:
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


def encode_create_env(
    spec: EnvSpec, client_id: str, count: int = 1, protocol_version: int = PROTOCOL_VERSION
) -> bytes:
    return encode(create_env(spec, client_id, count, protocol_version))


def encode_reset(
    seed: int | None = None, scenario: str | None = None, variation: int | None = None
) -> bytes:
    return encode(reset(seed, scenario, variation))


def encode_step(actions: Any, n_ext: int | None = None) -> bytes:
    return encode(step(actions, n_ext))


def encode_batch_step(env_ids: Iterable[str], actions: Any, n_ext: int | None = None) -> bytes:
    return encode(batch_step(env_ids, actions, n_ext))


def encode_close() -> bytes:
    return encode(close())


def encode_action_msg(action: Any, seq: int = 0) -> bytes:
    return encode(action_msg(action, seq))


def step_head(n_ext: int) -> bytes:
    """The bytes of a float32 ``Step`` of ``n_ext`` rows before its action data:
    ``step_head(n) + a.tobytes()`` equals ``encode_step(a)`` for a float32 ``[n, 2]`` array
    ``a`` (``data`` is the message's last field)."""
    n = int(n_ext)
    tail = 8 * n
    full = encode({"actions": {"dtype": "<f4", "shape": [n, 2], "data": bytes(tail)}})
    return full[:-tail] if tail else full


def batch_step_head(env_ids: Iterable[str]) -> bytes:
    """The bytes of a ``BatchStep`` before its actions array: a trainer stepping the same K envs
    again and again encodes them once; ``batch_step_head(ids) + encode(encode_array(a))`` equals
    ``encode_batch_step(ids, a)`` for a float32 array ``a``."""
    return b"\x82" + encode("env_ids") + encode(list(env_ids)) + encode("actions")
