"""Every message type fuzzed against its schema (issue 19): hypothesis starts from a valid
message and swaps fields for hostile values (wrong types, NaN/inf, huge and negative numbers,
empty and oversized lists, nested containers, unknown, missing and renamed fields). Each
payload decodes to a valid message or is refused with a named reason; nothing else escapes.
Through a real window stage on loopback Zenoh every refusal is counted exactly once, under its
reason, and the stage lives on."""

import io
import json
import math
import time
from collections import Counter
from dataclasses import fields

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from stream.bus import BusConfig, free_port, open_session
from stream.log import JsonLogger
from stream.stages import WindowStage
from stream.window import WindowConfig
from stream.worker import Received
from tests.stream.wire_examples import JOINT, TEMPERATURE, TRACKER, VALID
from wire import RejectedMessageError, decode, decode_model, key, to_dict

HOSTILE = st.one_of(
    st.none(),
    st.booleans(),
    st.integers(min_value=-(2**70), max_value=2**70),
    st.sampled_from([0, -1, 2**53, 2**53 + 1, 2**63, 10**300]),
    st.floats(allow_nan=True, allow_infinity=True),
    st.sampled_from([1e12, -1e12, 1e308, 5e-324, math.inf, -math.inf, math.nan]),
    st.text(max_size=12),
    st.sampled_from(["", "base", "tracker", "x" * 10_000]),
    st.lists(st.floats(allow_nan=True), max_size=12),
    st.lists(st.text(max_size=4), max_size=4),
    st.lists(st.integers(), min_size=0, max_size=3),
    st.dictionaries(st.text(max_size=4), st.floats() | st.text(max_size=3), max_size=3),
    st.recursive(st.integers(), lambda x: st.lists(x, max_size=2), max_leaves=12),
)
#: What a case found, for BENCHMARKS.md (printed by the last test with -s).
TALLY: Counter = Counter()


def mutate(data: st.DataObject, msg) -> dict:
    """A valid message's dict with one to three fields made hostile (or gone, or renamed)."""
    raw = to_dict(msg)
    names = [f.name for f in fields(msg)] * 4 + ["schema", "version"]
    for _ in range(data.draw(st.integers(1, 3))):
        name = data.draw(st.sampled_from(names))
        action = data.draw(st.sampled_from(["value", "value", "value", "drop", "rename"]))
        if action == "value":
            raw[name] = data.draw(HOSTILE)
        elif action == "drop":
            raw.pop(name, None)
        else:
            raw[name + "_"] = raw.pop(name, None)
    if raw.get("points") and isinstance(raw["points"], list) and data.draw(st.booleans()):
        raw["points"][0] = data.draw(HOSTILE)  # a hostile point inside a batch
    return raw


@settings(max_examples=400, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(data=st.data(), i=st.integers(0, len(VALID) - 1))
def test_every_message_type_fuzzed_against_its_schema_decodes_or_is_refused(data, i):
    msg = VALID[i]
    payload = json.dumps(mutate(data, msg)).encode()
    TALLY["cases"] += 1
    try:
        out = decode(payload, type(msg))
    except RejectedMessageError as exc:
        assert exc.reason and " " not in exc.reason
        TALLY[f"refused:{exc.reason}"] += 1
        return
    assert isinstance(out, type(msg))
    TALLY["valid"] += 1


@settings(max_examples=200, deadline=None)
@given(
    head=st.binary(max_size=8),
    header=st.one_of(
        st.binary(max_size=64),
        st.builds(
            lambda d: json.dumps(d).encode(),
            st.dictionaries(st.text(max_size=6), st.integers() | st.text(max_size=6), max_size=5),
        ),
    ),  # fmt: skip
    body=st.binary(max_size=256),
)
def test_model_frames_fuzzed_are_refused_with_a_reason(head, header, body):
    for payload in (head + header + body, len(header).to_bytes(8, "little") + header + body):
        TALLY["cases"] += 1
        try:
            decode_model(payload)
        except RejectedMessageError as exc:
            TALLY[f"refused:{exc.reason}"] += 1
            continue
        TALLY["valid"] += 1


@pytest.mark.integration
@settings(max_examples=1, deadline=None)
@given(st.data())
def test_a_window_stage_counts_every_refusal_once_under_its_reason(data):
    port = free_port()
    session = open_session(BusConfig.loopback(port, listen=True))
    cfg = WindowConfig(n_joints=6, require_temperatures=False)
    stage = WindowStage(session, "fuzz", "r1", cfg, JsonLogger(stream=io.StringIO()))
    try:
        sources = {"joints": JOINT, "tracker": TRACKER, "temperature": TEMPERATURE}
        n = 300
        for _ in range(n):
            stream = data.draw(st.sampled_from(sorted(sources)))
            payload = json.dumps(mutate(data, sources[stream])).encode()
            try:
                decode(payload, type(sources[stream]))
                reason = None
            except RejectedMessageError as exc:
                reason = exc.reason
            before = Counter(stage.counter.dropped)
            stage.worker.queue.put(Received(key("fuzz", "r1", stream), payload, None, time.time()))
            assert stage.drain(10)
            if reason is not None:  # refused at decode: counted once, under its reason
                assert Counter(stage.counter.dropped) - before == Counter({reason: 1})
        assert stage.failure is None and stage.worker.alive and stage.handled == n
        TALLY["stage_cases"] += n
    finally:
        stage.close(10)
        session.close()
    print(f"\nschema fuzz: {dict(sorted(TALLY.items()))}")
