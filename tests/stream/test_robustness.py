"""The pure parts of issue 24: schema bounds, the window's watermark and pin rules, the model
gate, atomic state writes on a full disk, and a worker that outlives bad messages."""

import json
import subprocess
import sys
import time

import numpy as np
import pytest
import torch

from kinematics.description import load_description
from learner.config import ModelConfig, TrainConfig
from learner.features import feature_spec
from learner.model import ErrorModel
from learner.snapshot import snapshot_to_bytes
from stream.trust import ModelGate, ModelTrustConfig, description_hash
from stream.window import Batcher, Joiner, WindowConfig
from stream.worker import Received, Worker
from tests.stream.wire_examples import decode_refusal
from wire import (
    MAX_DEPTH,
    Batch,
    JointSample,
    ModelHeader,
    RejectedMessageError,
    TemperatureSample,
    TrackerSample,
    encode,
    encode_model,
    parse_json,
)

CFG = WindowConfig(n_joints=1, require_temperatures=False, allowed_lateness_s=0.0)


@pytest.mark.parametrize(
    "payload, why",
    [
        (b"[" * 100_000 + b"]" * 100_000, "too_deep"),
        (b'{"a":' * (MAX_DEPTH + 1) + b"1" + b"}" * (MAX_DEPTH + 1), "too_deep"),
        (b'{"x":"' + b"a" * 5_000_000 + b'"}', "too_large"),
        (b"{not json", "malformed"),
    ],
)
def test_size_and_depth_are_limited_before_parsing(payload, why):
    t0 = time.perf_counter()
    assert decode_refusal(payload, JointSample) == why
    assert time.perf_counter() - t0 < 0.5


def test_brackets_inside_strings_do_not_count_as_depth():
    assert parse_json(b'{"a": "' + b"[" * 100 + b'"}') == {"a": "[" * 100}


def joint(seq=0, t=1.0, q=(0.1,)) -> JointSample:
    return JointSample(seq=seq, t=t, q=q)


@pytest.mark.parametrize(
    "field, value, why",
    [
        ("seq", "x", "out_of_range"),
        ("seq", 1e9, "out_of_range"),
        ("seq", -1, "out_of_range"),
        ("seq", 2**63, "out_of_range"),
        ("seq", True, "out_of_range"),
        ("t", 1e12, "out_of_range"),
        ("t", "now", "non_finite"),
    ],
)
def test_seq_and_t_are_bounded(field, value, why):
    raw = json.loads(encode(joint()))
    raw[field] = value
    assert decode_refusal(json.dumps(raw), JointSample) == why


def test_batch_seq_epoch_first_are_ints_in_range():
    raw = json.loads(encode(Batch(seq=1, points=())))
    for field, value in (("seq", "x"), ("seq", 1e9), ("epoch", -5), ("first", 2**60)):
        assert decode_refusal(json.dumps({**raw, field: value}), Batch) == "out_of_range"


def test_temperature_names_must_be_non_empty_and_unique():
    s = TemperatureSample(seq=0, t=1.0, names=(), values=())
    assert decode_refusal(encode(s), TemperatureSample) == "invalid"
    s = TemperatureSample(seq=0, t=1.0, names=("a", "a"), values=(1.0, 2.0))
    assert decode_refusal(encode(s), TemperatureSample) == "invalid"


def stream_joints(j: Joiner, t0: float, n: int, seq0: int = 0) -> None:
    for i in range(n):
        j.push(joint(seq=seq0 + i, t=t0 + i * 0.01))


def test_one_far_future_sample_is_refused_and_moves_no_watermark():
    j = Joiner(CFG)
    stream_joints(j, 0.0, 30)
    high = j._series["joints"].high
    j.push(joint(seq=10**6, t=1e9))
    assert j.counter.dropped["future"] == 1 and j._series["joints"].high == high
    stream_joints(j, 0.3, 10, seq0=30)  # the genuine stream goes on
    assert j.counter.dropped.get("late", 0) == 0
    tk = TrackerSample(seq=0, t=0.2, xyz=(1.0, 0.0, 0.0), quat=(0.0, 0.0, 0.0, 1.0))
    assert [p.t for p in j.push(tk)] == [0.2]


def test_a_stream_that_resumes_after_a_pause_is_accepted_after_confirmation():
    j = Joiner(CFG)
    stream_joints(j, 0.0, 30)
    stream_joints(j, 3600.0, 10, seq0=30)  # an hour later, same source
    assert j.counter.dropped["future"] == CFG.confirm_samples - 1
    assert j._series["joints"].high == pytest.approx(3600.09)


def test_wall_clock_refuses_live_samples_from_the_future_but_not_old_replays():
    j = Joiner(CFG)
    now = 1.8e9
    j.push(joint(seq=0, t=now + 3600.0), now=now)
    j.push(joint(seq=1, t=1.0), now=now)  # a replay of an old recording
    assert j.counter.dropped == {"future": 1} and j.counter.accepted == 1


def test_a_forged_name_list_or_frame_does_not_pin_the_window():
    cfg = WindowConfig(n_joints=1, allowed_lateness_s=0.0)
    j = Joiner(cfg)
    j.push(TemperatureSample(seq=0, t=0.0, names=("bogus",), values=(20.0,)))
    for i in range(1, 4):  # the genuine sensors: fewer than confirm_samples in a row
        j.push(TemperatureSample(seq=i, t=float(i), names=("ambient",), values=(20.0,)))
    assert j.counter.dropped["temperature_names"] == 3
    for i in range(4, 6):
        j.push(TemperatureSample(seq=i, t=float(i), names=("ambient",), values=(20.0,)))
    j.push(TemperatureSample(seq=9, t=9.0, names=("bogus",), values=(20.0,)))
    assert j._temperature_names.value == ("ambient",)
    assert j.counter.dropped["temperature_names"] == 5
    tk = TrackerSample(seq=0, t=10.0, xyz=(1.0, 0.0, 0.0), quat=(0.0, 0.0, 0.0, 1.0))
    j.push(tk)
    j.push(TrackerSample(seq=1, t=11.0, xyz=(1.0, 0.0, 0.0), quat=(0, 0, 0, 1.0), frame="tracker"))
    assert j.counter.dropped["frame"] == 1


def test_a_source_that_restarts_its_numbering_is_not_time_backwards():
    j = Joiner(CFG)
    stream_joints(j, 0.0, 30, seq0=500)
    stream_joints(j, 0.5, 10, seq0=0)
    assert j.counter.dropped == {} and j.counter.accepted == 40


def test_batcher_continues_its_numbering_and_point_index():
    b = Batcher(2, epoch=7, seq=3, count=11)
    p = object()
    (batch,) = b.add([p, p])  # type: ignore[list-item]
    assert (batch.epoch, batch.seq, batch.first, b.next_seq, b.count) == (7, 3, 11, 4, 13)


@pytest.fixture(scope="module")
def models():
    torch.set_num_threads(1)
    fanuc, ur10 = load_description("fanuc_m900ib700"), load_description("ur10")
    small = ModelConfig(hidden_layers=1, neurons=8)

    def snap(desc, n_temps=1, sec=True):
        spec = feature_spec(desc, n_temps, sec, ("ambient",)[:n_temps])
        return snapshot_to_bytes(ErrorModel.create(spec, small, TrainConfig(), 0))

    return fanuc, snap(fanuc), snap(ur10), snap(fanuc, 0, False)


def framed(snap, version, robot="fanuc1", n_seen=1000):
    return encode_model(ModelHeader(model_version=version, robot=robot, n_seen=n_seen, t=1.0), snap)


def refusal(gate, payload) -> str:
    with pytest.raises(RejectedMessageError) as exc:
        gate.admit(payload)
    return exc.value.reason


def test_model_gate_adopts_only_models_of_this_cell(models):
    fanuc, genuine, ur10, other_features = models
    gate = ModelGate("fanuc1", fanuc, ModelTrustConfig(max_version_jump=10))
    assert gate.admit(framed(genuine, 1))[0].model_version == 1
    assert refusal(gate, framed(ur10, 2)) == "model_foreign"
    assert refusal(gate, framed(genuine, 2, robot="ur10")) == "model_foreign"
    assert refusal(gate, framed(other_features, 2)) == "model_foreign"
    assert refusal(gate, framed(genuine, 10**9, n_seen=10**9 + 5)) == "model_version"
    assert refusal(gate, framed(genuine, 50, n_seen=10)) == "model_version"
    assert refusal(gate, framed(genuine[:100], 2)) == "snapshot"
    assert gate.admit(framed(genuine, 2))[0].model_version == 2
    assert refusal(gate, framed(genuine, 2)) == "model_old" and gate.version == 2


def test_a_restarted_learner_is_adopted_after_confirmation(models):
    fanuc, genuine, _, _ = models
    gate = ModelGate("fanuc1", fanuc, ModelTrustConfig(confirm_models=3))
    gate.admit(framed(genuine, 90))
    assert refusal(gate, framed(genuine, 1)) == "model_old"
    assert refusal(gate, framed(genuine, 2)) == "model_old"
    assert gate.admit(framed(genuine, 3))[0].model_version == 3


def test_description_hash_ignores_the_tool_but_not_the_arm(models):
    fanuc = models[0]
    assert description_hash(fanuc) == description_hash(fanuc.with_tool(np.eye(4) * 1.0))
    assert description_hash(fanuc) != description_hash(load_description("ur10"))


def test_a_full_disk_leaves_no_temporary_file_and_the_old_state(tmp_path):
    """A real EFBIG (RLIMIT_FSIZE) stands in for ENOSPC: the write fails part-way."""
    target = tmp_path / "ckpt.bin"
    target.write_bytes(b"good")
    code = (
        "import resource, sys\n"
        "from stream.state import write_atomic\n"
        "resource.setrlimit(resource.RLIMIT_FSIZE, (4096, 4096))\n"
        "try:\n"
        f"    write_atomic({str(target)!r}, b'x' * 100_000)\n"
        "except OSError as exc:\n"
        "    print(exc.errno); sys.exit(3)\n"
    )
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True)
    assert proc.returncode == 3, proc.stderr
    assert target.read_bytes() == b"good" and sorted(tmp_path.iterdir()) == [target]


def test_a_worker_survives_bad_items_only_through_its_stage_and_dies_on_resources():
    seen = []

    def handle(item):
        if item.payload == b"disk":
            raise OSError(28, "No space left on device")
        seen.append(item.payload)

    w = Worker("t", handle)
    for payload in (b"a", b"disk", b"b"):
        w.queue.put(Received("k", payload, None, 0.0))
    assert not w.drain(2.0)
    assert isinstance(w.error, OSError) and seen == [b"a"] and not w.alive
    assert w.stop(1.0)
