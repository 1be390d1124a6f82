"""Wire messages: round trips, every rejection reason, model framing, key expressions."""

import json
import math

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from kinematics.errors import SchemaError
from tests.stream.wire_examples import HEADER, JOINT, SAMPLES, VALID
from wire import (
    DropCounter,
    JointSample,
    RejectedMessageError,
    TemperatureSample,
    TrackerSample,
    decode,
    decode_model,
    encode,
    encode_model,
    key,
    split_key,
    to_dict,
)


@pytest.mark.parametrize("msg", SAMPLES)
def test_round_trip(msg):
    assert decode(encode(msg), type(msg)) == msg


@pytest.mark.parametrize("msg", VALID)
def test_encode_writes_the_json_of_to_dict(msg):
    """``encode`` skips ``to_dict``'s deep copy; what it writes is the same, nested points and
    dict fields included."""
    assert encode(msg) == json.dumps(to_dict(msg), separators=(",", ":")).encode()


def test_encode_refuses_a_field_json_cannot_write():
    with pytest.raises(TypeError, match="complex is not JSON serializable"):
        encode(JointSample(seq=1, t=1.0, q=(1j,)))


def _joint(**changes) -> bytes:
    raw = json.loads(encode(JOINT))
    raw.update(changes)
    return json.dumps(raw).encode()


@pytest.mark.parametrize(
    "payload, cls, reason",
    [
        (b"{not json", JointSample, "malformed"),
        (b"[1, 2]", JointSample, "malformed"),
        (_joint(schema="robocal.tracker"), JointSample, "schema"),
        (_joint(version=99), JointSample, "version"),
        (_joint(q=[0.1, float("nan"), 0, 0, 0, 0]), JointSample, "non_finite"),
        (_joint(t=float("inf")), JointSample, "non_finite"),
        (_joint(q=[0.1, 100.0, 0, 0, 0, 0]), JointSample, "out_of_range"),
        (_joint(q=[0.1, "x", 0, 0, 0, 0]), JointSample, "non_finite"),
        (_joint(seq=-1), JointSample, "out_of_range"),
        (_joint(qs=[0.0] * 5), JointSample, "joint_count"),
        (
            json.dumps({"schema": "robocal.joints", "version": 1, "t": 0.0}).encode(),
            JointSample,
            "malformed",
        ),
        (
            encode(TrackerSample(seq=0, t=0.0, xyz=(1, 0, 0), quat=(0, 0, 0, 1.5))),
            TrackerSample,
            "quaternion",
        ),
        (
            encode(TemperatureSample(seq=0, t=0.0, names=("a",), values=(500.0,))),
            TemperatureSample,
            "out_of_range",
        ),
    ],
)
def test_rejections_name_their_reason(payload, cls, reason):
    with pytest.raises(RejectedMessageError) as info:
        decode(payload, cls)
    assert info.value.reason == reason
    assert isinstance(info.value, SchemaError)
    assert "\n" not in str(info.value)


def test_nan_survives_encoding_and_is_rejected():
    raw = encode(JointSample(seq=0, t=0.0, q=(math.nan,) * 6))
    with pytest.raises(RejectedMessageError, match="non_finite"):
        decode(raw, JointSample)


def test_model_framing_round_trip():
    blob = b"\x00safetensors bytes\xff"
    assert decode_model(encode_model(HEADER, blob)) == (HEADER, blob)


@pytest.mark.parametrize("payload", [b"", b"\x05\x00\x00\x00\x00\x00\x00\x00{}", b"\xff" * 8])
def test_bad_model_payload_is_rejected(payload):
    with pytest.raises(RejectedMessageError):
        decode_model(payload)


def test_keys():
    assert split_key(key("c", "r", "model")) == ("c", "r", "model")
    with pytest.raises(SchemaError):
        key("c", "r", "nope")
    with pytest.raises(RejectedMessageError):
        split_key("robocal/c/r")


def test_drop_counter():
    c = DropCounter("window")
    c.drop("late")
    c.drop("late")
    c.accept(3)
    d = c.diagnostics(t=1.0)
    assert (d.accepted, d.dropped, d.stage) == (3, {"late": 2}, "window")


JSON = st.recursive(
    st.none() | st.booleans() | st.integers() | st.floats() | st.text(max_size=5),
    lambda inner: st.lists(inner, max_size=7) | st.dictionaries(st.text(max_size=5), inner),
    max_leaves=20,
)


@settings(max_examples=300, deadline=None)
@given(
    cls=st.sampled_from([type(m) for m in SAMPLES]),
    values=st.dictionaries(
        st.sampled_from(
            [
                "seq",
                "t",
                "q",
                "qs",
                "xyz",
                "quat",
                "frame",
                "names",
                "values",
                "points",
                "temperatures",
                "temperature_names",
            ]
        ),
        JSON,
    ),
)
def test_any_json_is_either_a_valid_message_or_rejected(cls, values):
    payload = json.dumps({"schema": cls.SCHEMA, "version": 1, **values}).encode()
    try:
        msg = decode(payload, cls)
    except RejectedMessageError:
        return
    assert isinstance(msg, cls)
