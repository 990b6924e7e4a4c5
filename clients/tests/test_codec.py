"""The wire modules against the golden wire samples (tests/golden/, described in its README.md)."""

from __future__ import annotations

import json
import re
from pathlib import Path

import msgspec
import numpy as np
import pytest

from sharedspace.wire import EnvSpec, envelope, errors, replies, requests

GOLDEN = Path(__file__).resolve().parents[2] / "tests" / "golden"
FILES = sorted(p.name for p in GOLDEN.glob("*.msgpack"))


# ---------------------------------------------------------------------------------------------
# A parser of the README's notation.


class _Array:
    def __init__(self, dtype, shape, data):
        self.dtype, self.shape, self.data = dtype, shape, data


_TOKEN = re.compile(
    r"""\s*(?:
        (?P<array>array\ dtype=(?P<dt>\S+)\ shape=\[(?P<shape>[^\]]*)\]
                  \ data\(row-major\)=\[(?P<data>[^\]]*)\])
      | (?P<str>"(?:[^"\\]|\\.)*")
      | (?P<num>-?\d+(?:\.\d+)?(?:[eE][-+]?\d+)?)
      | (?P<word>nil|true|false)
      | (?P<punct>[{}\[\]:,])
    )""",
    re.VERBOSE,
)


def _tokens(text):
    pos = 0
    out = []
    text = text.rstrip()
    while pos < len(text):
        m = _TOKEN.match(text, pos)
        if not m:
            raise ValueError(f"cannot tokenize README at {text[pos : pos + 40]!r}")
        pos = m.end()
        out.append(m)
    return out


def _parse(tokens, i=0):
    """Recursive descent over the README notation (commas optional, newlines separate)."""
    m = tokens[i]
    if m.group("array"):
        shape = [int(s) for s in m.group("shape").split(",") if s.strip()]
        data = [float(s) for s in m.group("data").split(",") if s.strip()]
        return _Array(m.group("dt"), shape, data), i + 1
    if m.group("str"):
        return json.loads(m.group("str")), i + 1
    if m.group("num"):
        s = m.group("num")
        return (float(s) if ("." in s or "e" in s.lower()) else int(s)), i + 1
    if m.group("word"):
        return {"nil": None, "true": True, "false": False}[m.group("word")], i + 1
    p = m.group("punct")
    if p in ("{", "["):  # a map of `key: value` items or an array, items separated by commas
        close, items = "}" if p == "{" else "]", []
        i += 1
        while tokens[i].group("punct") != close:
            if tokens[i].group("punct") == ",":
                i += 1
                continue
            item, i = _parse(tokens, i)
            if p == "{":
                assert tokens[i].group("punct") == ":"
                value, i = _parse(tokens, i + 1)
                item = (item, value)
            items.append(item)
        return (dict(items) if p == "{" else items), i + 1
    raise ValueError(f"unexpected token {m.group(0)!r}")


def readme_samples() -> dict[str, tuple[int, object]]:
    text = (GOLDEN / "README.md").read_text()
    samples = {}
    for m in re.finditer(
        r"^## `(?P<name>[a-z_0-9]+\.msgpack)`.*?(?P<size>\d+) bytes.*?```text\n(?P<body>.*?)```",
        text,
        re.S | re.M,
    ):
        value, end = _parse(_tokens(m.group("body")))
        samples[m.group("name")] = (int(m.group("size")), value)
    return samples


SAMPLES = readme_samples()


def _assert_matches(decoded, documented, path="$"):
    if isinstance(documented, _Array):
        assert isinstance(decoded, np.ndarray), f"{path}: expected an array"
        assert decoded.dtype.str == documented.dtype, path
        assert list(decoded.shape) == documented.shape, path
        want = np.array(documented.data, dtype=np.float64)
        if decoded.dtype == np.float32:
            want = want.astype(np.float32)  # the README prints the shortest f32 round trip
        np.testing.assert_array_equal(decoded.reshape(-1), want.astype(decoded.dtype), err_msg=path)
    elif isinstance(documented, dict):
        assert isinstance(decoded, dict), path
        assert list(decoded.keys()) == list(documented.keys()), f"{path}: key order"
        for k in documented:
            _assert_matches(decoded[k], documented[k], f"{path}.{k}")
    elif isinstance(documented, list):
        assert isinstance(decoded, list) and len(decoded) == len(documented), path
        for k, (a, b) in enumerate(zip(decoded, documented, strict=True)):
            _assert_matches(a, b, f"{path}[{k}]")
    elif isinstance(documented, float):
        assert isinstance(decoded, float) and decoded == documented, f"{path}: {decoded!r}"
    else:
        assert type(decoded) is type(documented) and decoded == documented, f"{path}: {decoded!r}"


def test_readme_documents_every_file():
    assert FILES and sorted(SAMPLES) == FILES


@pytest.mark.parametrize("name", FILES)
def test_golden_decodes_to_documented_values(name):
    payload = (GOLDEN / name).read_bytes()
    size, documented = SAMPLES[name]
    assert len(payload) == size
    _assert_matches(envelope.decode(payload), documented)


@pytest.mark.parametrize("name", FILES)
def test_golden_reencodes_byte_identically(name):
    payload = (GOLDEN / name).read_bytes()
    assert envelope.encode(envelope.decode(payload)) == payload


def test_arrays_are_zero_copy_views():
    payload = (GOLDEN / "states.msgpack").read_bytes()
    m = envelope.decode(payload)
    pos = m["positions"]
    assert not pos.flags.owndata and not pos.flags.writeable
    raw = envelope.decode(payload, arrays=False)["positions"]["data"]
    assert pos.tobytes() == raw
    assert pos.dtype == np.float64 and pos.shape == (3, 2)
    assert m["kinds"].dtype == np.uint8 and m["ids"].dtype == np.uint32


def _golden(name):
    return (GOLDEN / name).read_bytes()


def test_request_builders_reproduce_golden_bytes():
    assert requests.encode_info_request() == _golden("info_request.msgpack")
    spec = EnvSpec(
        pool="hbs_3ped",
        seed=42,
        pedestrian_params={"lambda1": 1.5, "tau": 0.5},
        reward_weights={"collision": -25.0},
        max_agents=4,
        autoreset=True,
    )
    assert requests.encode_create_env(spec, "trainer-a", count=2) == _golden("create_env.msgpack")
    assert requests.encode_reset(seed=7) == _golden("reset.msgpack")
    act = np.array([[0.5, -1.25]], dtype=np.float32)
    assert requests.encode_step(act, n_ext=1) == _golden("step.msgpack")
    assert requests.encode_step(act.astype(np.float64)) == _golden("step_f64.msgpack")
    assert requests.encode_step([0.5, -1.25]) == _golden("step_f64.msgpack")  # [2] -> [1, 2]
    batch = np.array([[[0.5, -1.25]], [[-0.25, 0.0]]], dtype=np.float32)
    assert requests.encode_batch_step(["s1-0", "s1-1"], batch) == _golden("batch_step.msgpack")
    assert requests.encode_close() == _golden("close.msgpack")
    assert requests.encode_action_msg(np.float32([0.25, 0.0]), seq=17) == _golden("action.msgpack")


def test_env_spec_holds_the_fields_of_the_rust_create_env():
    """EnvSpec and protocol's CreateEnv hold the same fields, in the same order and of the same
    wire types: a spec with every optional field set encodes to the Rust sample's bytes
    (create_env_full.msgpack), and the request's own fields are the rest."""
    spec = EnvSpec(
        split="test",
        external_agents=("vehicle_0", "vehicle_1"),
        mode="realtime",
        scenario="synthetic-counter_flow-n12-v2-intersection-seed3",
        realtime_factor=2.0,
        synthetic={
            "layout": "counter_flow",
            "pedestrians": 12,
            "vehicles": 2,
            "routes": "intersection",
            "density": 0.5,
            "seed": 3,
            "scenes": 4,
        },
        exclude=("hbs-car1130",),
        composed={
            "scenes": 1000,
            "seed": 7,
            "source": "hbs-paper",
            "hold_out": ["hbs-car1116"],
            "pedestrians": 3,
            "shares": {"crossing": 0.5},
            "other_cars": False,
        },
        variations={
            "position_sigma": 0.25,
            "start_offset_steps": 1,
            "desired_speed_scale": 0.1,
            "param_noise": {"tau": 0.2},
            "mirror": True,
            "rotation_deg": 15.0,
        },
        vehicle_model="idm",
        pedestrian_params={"lambda1": 1.5, "tau": 0.5},
        reward_weights={"collision": -25.0},
        max_agents=4,
        autoreset=True,
        seed=42,
    )
    golden = _golden("create_env_full.msgpack")
    assert requests.encode_create_env(spec, "trainer-a", count=2) == golden
    rust_fields = list(msgspec.msgpack.decode(golden))
    assert rust_fields == ["protocol_version", "client_id", "count", *EnvSpec.fields()]


@pytest.mark.parametrize(
    "fields, names",
    [
        ({"vehicle_model": "teleport"}, "EnvSpec.vehicle_model"),
        ({"max_agents": "8"}, "EnvSpec.max_agents"),
        ({"seed": -1}, "EnvSpec.seed"),
        ({"variations": {"positon_sigma": 0.5}}, "positon_sigma"),
        ({"synthetic": {"layout": "grid"}}, "EnvSpec.synthetic"),
        ({"synthetic": {"routes": "ring"}}, "EnvSpec.synthetic"),
        ({"composed": {"scenes": 0}}, "EnvSpec.composed"),
        ({"composed": {"shares": {"crosing": 1.0}}}, "crosing"),
    ],
)
def test_an_ill_typed_env_field_is_refused_where_it_is_written(fields, names):
    with pytest.raises(ValueError, match=re.escape(names)):
        EnvSpec(**fields)
    with pytest.raises(ValueError, match=re.escape(names)):
        EnvSpec().replace(**fields)


def test_a_misspelt_env_field_is_refused_by_name():
    with pytest.raises(TypeError, match="vehicle_modle"):
        EnvSpec(vehicle_modle="idm")
    from sharedspace.client import env_options

    with pytest.raises(TypeError, match="max_agent'.*EnvSpec.*max_agents"):
        env_options({"max_agent": 4})


def test_an_env_spec_survives_pickling():
    import pickle

    spec = EnvSpec(pool="hbs-general", vehicle_model="idm", variations={"mirror": True})
    assert pickle.loads(pickle.dumps(spec)) == spec


def test_wrong_action_shapes_raise_wrong_shape():
    with pytest.raises(errors.WrongShape):
        requests.step(np.zeros((2, 3)))
    with pytest.raises(errors.WrongShape):
        requests.step(np.zeros((2, 2)), n_ext=1)
    with pytest.raises(errors.WrongShape):
        requests.batch_step(["a", "b"], np.zeros((3, 1, 2), dtype=np.float32))
    with pytest.raises(errors.WrongShape):
        requests.action_msg([1.0, 2.0, 3.0])
    # Integer actions are sent as float64 (the server refuses integer dtypes).
    assert requests.step([[1, 0]])["actions"].dtype == np.float64


def test_reply_envelope():
    info = replies.decode_result(_golden("reply_server_info.msgpack"))
    assert info["server_id"] == "s1" and info["pools"][0]["name"] == "hbs_3ped"
    step = replies.decode_result(_golden("reply_step.msgpack"))
    assert step["obs"]["features"].shape == (1, 4, 11)
    assert step["reward"].dtype == np.float32 and step["reward"][0] == np.float32(-1.125)
    with pytest.raises(errors.NonFiniteAction) as e:
        replies.decode_result(_golden("reply_error.msgpack"))
    assert isinstance(e.value, errors.ServerError) and isinstance(e.value, errors.SharedspaceError)
    assert e.value.code == "non_finite_action" and e.value.env_id == "s1-1"
    assert "component 1 is NaN" in e.value.message


@pytest.mark.parametrize(
    ("code", "cls"),
    [
        ("version_mismatch", errors.VersionMismatch),
        ("env_closed", errors.EnvClosed),
        ("wrong_shape", errors.WrongShape),
        ("something_new", errors.ServerError),
    ],
)
def test_error_codes_map_to_exceptions(code, cls):
    payload = envelope.encode(envelope.error(code, "msg"))
    with pytest.raises(cls) as e:
        replies.decode_result(payload)
    assert type(e.value) is cls and e.value.code == code and e.value.env_id is None


def test_bad_payloads_raise_protocol_error():
    with pytest.raises(errors.ProtocolError):
        replies.decode_result(envelope.encode({"ok": 1, "error": {"code": "x", "message": "y"}}))
    with pytest.raises(errors.ProtocolError):
        replies.decode_result(envelope.encode({"neither": 1}))
    with pytest.raises(errors.ProtocolError):
        envelope.decode(_golden("close.msgpack") + b"\x00")  # trailing bytes
    bad_len = {"dtype": "<f4", "shape": [3], "data": b"\x00" * 8}
    with pytest.raises(errors.ProtocolError):
        envelope.decode(msgspec.msgpack.encode({"a": bad_len}))
    bad_dtype = {"dtype": "<i8", "shape": [1], "data": b"\x00" * 8}
    with pytest.raises(errors.ProtocolError):
        envelope.decode(msgspec.msgpack.encode({"a": bad_dtype}))
    assert envelope.decode(b"") == {}


def test_no_server_error():
    e = errors.NoServer("sharedspace/server/*/info", 5.0)
    assert e.endpoint == "sharedspace/server/*/info" and e.timeout == 5.0
    assert "5 s" in str(e) and isinstance(e, errors.SharedspaceError)


# --------------------------------------------------------------------------------------------
# The client's hot-path reply decoder must agree with the careful generic one.


def _same(a, b):
    if isinstance(a, np.ndarray) or isinstance(b, np.ndarray):
        return (
            isinstance(a, np.ndarray)
            and isinstance(b, np.ndarray)
            and a.dtype == b.dtype
            and a.shape == b.shape
            and np.array_equal(a, b)
        )
    if isinstance(a, dict):
        return isinstance(b, dict) and a.keys() == b.keys() and all(_same(a[k], b[k]) for k in a)
    if isinstance(a, list):
        return isinstance(b, list) and len(a) == len(b) and all(map(_same, a, b))
    return a == b


#: (field, malformed value, what the error says) for the client decoders.
MALFORMED_ARRAYS = [
    ("reward", None, "expected a binary-array map"),
    ("reward", {"dtype": "<f4", "shape": [1]}, "expected a binary-array map"),
    ("reward", {"dtype": "<f4", "shape": [3], "data": b"\0" * 4}, "needs 12"),
    ("terminated", {"dtype": "<i8", "shape": [1], "data": b"\0" * 8}, "unsupported dtype"),
    ("reward", {"dtype": "<f4", "shape": [-1], "data": b""}, "non-negative"),
]


@pytest.mark.parametrize("name", ["reply_step", "reply_reset", "reply_batch_step"])
def test_client_decode_result_equals_the_generic_decoding(name):
    """The reply decoder's arrays and maps are the generic decoder's (every map, every array)."""
    payload = (GOLDEN / f"{name}.msgpack").read_bytes()
    generic = envelope.unwrap_reply(envelope.decode(payload))
    assert _same(replies.decode_result(payload), generic)


@pytest.mark.parametrize(
    "field, value, says",
    MALFORMED_ARRAYS,
)
def test_client_decode_result_names_a_malformed_array(field, value, says):
    from sharedspace.wire.replies import decode_result

    reply = msgspec.msgpack.decode((GOLDEN / "reply_step.msgpack").read_bytes())
    reply["ok"][field] = value
    with pytest.raises(errors.ProtocolError, match=says):
        decode_result(msgspec.msgpack.encode(reply))


@pytest.mark.parametrize(
    "field, value, says",
    MALFORMED_ARRAYS,
)
@pytest.mark.parametrize("name", ["reply_step", "reply_batch_step"])
def test_client_typed_decoders_name_a_malformed_array(name, field, value, says):
    from sharedspace.wire.replies import decode_batch_result, decode_step_result

    decode = decode_step_result if name == "reply_step" else decode_batch_result
    reply = msgspec.msgpack.decode((GOLDEN / f"{name}.msgpack").read_bytes())
    reply["ok"][field] = value
    with pytest.raises(errors.ProtocolError, match=says):
        decode(msgspec.msgpack.encode(reply))


@pytest.mark.parametrize(
    "mangle, says",
    [
        (lambda b: b + b"\x00", "trailing"),
        (lambda b: b[:-3], "truncated"),
        (lambda b: b"\xc1" + b, "malformed"),
        (lambda b: b"", "empty reply"),
    ],
)
def test_client_decode_result_refuses_undecodable_bytes(mangle, says):
    from sharedspace.wire.replies import decode_result

    with pytest.raises(errors.ProtocolError, match=says):
        decode_result(mangle((GOLDEN / "reply_step.msgpack").read_bytes()))


@pytest.mark.parametrize("k", [1, 16, 300])
def test_batch_step_head_plus_actions_is_the_whole_request(k):
    ids = [f"srv-{i}" for i in range(k)]
    actions = np.random.default_rng(k).uniform(-1, 1, (k, 1, 2)).astype(np.float32)
    head = requests.batch_step_head(ids)
    assert head + envelope.encode(actions) == requests.encode_batch_step(ids, actions)


def test_client_batch_decoder_equals_decode_result():
    from sharedspace.wire.replies import decode_batch_result

    payload = (GOLDEN / "reply_batch_step.msgpack").read_bytes()
    typed = decode_batch_result(payload)
    assert _same(typed, replies.decode_result(payload))
    # the arrays are views of the payload itself, not copies
    assert typed["obs"]["features"].base is not None
    assert not typed["obs"]["features"].flags.writeable
    # env ids known to the caller are taken as they are only when the reply says the same
    ids = ["s1-0", "s1-1"]
    known = decode_batch_result(payload, (envelope.encode(ids), ids))
    assert known["env_ids"] == ids and known["env_ids"] is not ids
    other = ["s1-0", "s1-9"]
    assert decode_batch_result(payload, (envelope.encode(other), other))["env_ids"] == ids


def test_client_step_decoder_equals_decode_result():
    from sharedspace.wire.replies import decode_step_result

    payload = (GOLDEN / "reply_step.msgpack").read_bytes()
    assert _same(decode_step_result(payload), replies.decode_result(payload))
    # with an autoreset (the generic path) and as an error reply
    reply = msgspec.msgpack.decode((GOLDEN / "reply_reset.msgpack").read_bytes())
    step = msgspec.msgpack.decode(payload)
    step["ok"]["reset"] = reply["ok"]
    with_reset = msgspec.msgpack.encode(step)
    assert _same(decode_step_result(with_reset), replies.decode_result(with_reset))
    with pytest.raises(errors.NonFiniteAction):
        decode_step_result((GOLDEN / "reply_error.msgpack").read_bytes())
    step["ok"]["reward"] = {"dtype": "<f4", "shape": [2], "data": b"\0" * 4}
    with pytest.raises(errors.ProtocolError, match="needs 8"):
        decode_step_result(msgspec.msgpack.encode(step))


def test_client_batch_decoder_raises_what_the_generic_decoder_raises():
    from sharedspace.wire.replies import decode_batch_result

    with pytest.raises(errors.NonFiniteAction):
        decode_batch_result((GOLDEN / "reply_error.msgpack").read_bytes())
    reply = msgspec.msgpack.decode((GOLDEN / "reply_batch_step.msgpack").read_bytes())
    reply["ok"]["reward"] = {"dtype": "<f4", "shape": [5, 1], "data": b"\0" * 8}
    with pytest.raises(errors.ProtocolError, match="needs 20"):
        decode_batch_result(msgspec.msgpack.encode(reply))
    reply["ok"]["reward"] = {"dtype": "<f4", "shape": [3], "data": 7}  # not even bytes
    with pytest.raises(errors.ProtocolError, match="binary-array map"):
        decode_batch_result(msgspec.msgpack.encode(reply))
    with pytest.raises(errors.ProtocolError, match="empty reply"):
        decode_batch_result(b"")


@pytest.mark.parametrize("shape", [(1, 1, 2), (16, 3, 2), (300, 1, 2), (0, 1, 2)])
def test_f32_array_head_plus_data_is_the_encoded_array(shape):
    a = np.random.default_rng(len(shape)).uniform(-1, 1, shape).astype(np.float32)
    assert envelope.f32_array_head(shape) + a.tobytes() == envelope.encode(a)


@pytest.mark.parametrize("n_ext", [0, 1, 3])
def test_step_head_plus_action_bytes_is_the_whole_request(n_ext):
    actions = np.random.default_rng(n_ext).uniform(-1, 1, (n_ext, 2)).astype(np.float32)
    assert requests.step_head(n_ext) + actions.tobytes() == requests.encode_step(actions)


@pytest.mark.parametrize(
    "m",
    [
        {"dtype": "<f4", "shape": [], "data": np.float32(2.5).tobytes()},
        {"dtype": "<u4", "shape": [2, 0, 3], "data": b""},
        {"dtype": "|u1", "shape": [2, 3], "data": bytes(range(6))},
    ],
)
def test_client_array_views_equal_decode_array(m):
    from sharedspace.wire.replies import _array

    assert _same(_array(m), envelope.decode_array(m))


def test_client_array_refuses_negative_dims_of_a_matching_size():
    from sharedspace.wire.replies import _array

    with pytest.raises(errors.ProtocolError, match="non-negative"):
        _array({"dtype": "<f4", "shape": [-1, -1], "data": b"\0" * 4})


def test_client_layout_decoder_equals_the_typed_step_decoder():
    from sharedspace.wire.replies import _StepLayout, decode_step_result, step_decoder_for

    payload = (GOLDEN / "reply_step.msgpack").read_bytes()
    first = decode_step_result(payload)
    layout = step_decoder_for(first)
    assert isinstance(layout, _StepLayout)
    assert step_decoder_for(decode_step_result(payload)) is layout  # one per layout
    out = layout(payload)
    assert _same(out, first) and _same(out, replies.decode_result(payload))
    assert out["obs"]["features"].base is not None  # a view of the payload
    assert not out["reward"].flags.writeable


@pytest.mark.parametrize(
    "mangle",
    [
        lambda ok: ok.update(reward={"dtype": "<f4", "shape": [2], "data": b"\0" * 8}),
        lambda ok: ok.update(reward={"dtype": "<f8", "shape": [1], "data": b"\0" * 8}),
        lambda ok: ok["obs"].update(mask={"dtype": "|u1", "shape": [1, 3], "data": b"\0" * 3}),
        lambda ok: ok["reward_terms"].update(
            extra={"dtype": "<f4", "shape": [3], "data": b"\0" * 12}
        ),
        lambda ok: ok.update(
            reset=msgspec.msgpack.decode((GOLDEN / "reply_reset.msgpack").read_bytes())["ok"]
        ),
    ],
    ids=["other_shape", "other_dtype", "other_obs_shape", "other_term_shape", "autoreset"],
)
def test_client_layout_decoder_hands_replies_off_its_layout_to_the_typed_decoder(mangle):
    from sharedspace.wire.replies import decode_step_result, step_decoder_for

    payload = (GOLDEN / "reply_step.msgpack").read_bytes()
    layout = step_decoder_for(decode_step_result(payload))
    reply = msgspec.msgpack.decode(payload)
    mangle(reply["ok"])
    other = msgspec.msgpack.encode(reply)
    assert _same(layout(other), decode_step_result(other))


@pytest.mark.parametrize(
    "field, value, says",
    [
        ("reward", {"dtype": "<f4", "shape": [1], "data": b"\0" * 8}, "needs 4"),
        ("reward", {"dtype": "<f4", "shape": [3], "data": b"\0" * 4}, "needs 12"),
        ("terminated", {"dtype": "<i8", "shape": [1], "data": b"\0" * 8}, "unsupported dtype"),
        ("reward", None, "expected a binary-array map"),
    ],
)
def test_client_layout_decoder_names_a_malformed_array(field, value, says):
    from sharedspace.wire.replies import decode_step_result, step_decoder_for

    payload = (GOLDEN / "reply_step.msgpack").read_bytes()
    layout = step_decoder_for(decode_step_result(payload))
    reply = msgspec.msgpack.decode(payload)
    reply["ok"][field] = value
    with pytest.raises(errors.ProtocolError, match=says):
        layout(msgspec.msgpack.encode(reply))
    with pytest.raises(errors.NonFiniteAction):
        layout((GOLDEN / "reply_error.msgpack").read_bytes())


def test_an_ill_typed_connection_is_refused_by_name():
    from sharedspace.client import Connection

    with pytest.raises(ValueError, match=re.escape("Connection.zenoh_mode")):
        Connection(zenoh_mode="router")
    with pytest.raises(ValueError, match=re.escape("Connection.timeout")):
        Connection().replace(timeout="soon")
