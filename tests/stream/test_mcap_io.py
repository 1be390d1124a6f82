"""MCAP record/replay: channels and times, and a SIGKILLed recorder leaves a readable file."""

import json
import signal
import subprocess
import sys
import time

import pytest
from mcap.reader import make_reader

from stream.bus import BusConfig, free_port, open_session
from stream.cli import main
from stream.mcap_io import McapRecorder, read_mcap, recorded_samples, replay_to_bus
from stream.messages import JointSample, ModelHeader, TrackerSample, encode, encode_model

RECORDER_SCRIPT = """
import sys, time
from stream.mcap_io import McapRecorder
from stream.messages import JointSample, encode
r = McapRecorder(sys.argv[1], flush_interval_s=0.05)
i = 0
while True:
    r.add("robocal/c/r/joints", encode(JointSample(seq=i, t=i * 0.008, q=(0.0,) * 6)))
    i += 1
    if i == 500:
        print("ready", flush=True)
    time.sleep(0.0002)
"""


def test_record_and_read_back(tmp_path):
    path = tmp_path / "rec.mcap"
    rec = McapRecorder(path)
    joint = encode(JointSample(seq=0, t=2.5, q=(0.0,) * 6))
    rec.add("robocal/c/r/joints", joint, log_time_ns=2_000)
    rec.add(
        "robocal/c/r/tracker",
        encode(TrackerSample(seq=0, t=3.0, xyz=(1, 0, 0), quat=(0, 0, 0, 1))),
        log_time_ns=1_000,
    )
    model = encode_model(ModelHeader(model_version=1, robot="r", n_seen=5, t=4.0), b"weights")
    rec.add("robocal/c/r/model", model, log_time_ns=3_000)
    rec.add("robocal/c/r/joints", b"{broken", log_time_ns=4_000)
    rec.close()
    got = list(read_mcap(path))
    assert [r.log_time_ns for r in got] == [1_000, 2_000, 3_000, 4_000]
    assert [r.publish_time_ns for r in got] == [3_000_000_000, 2_500_000_000, 4_000_000_000, 4_000]
    assert got[1].payload == joint and got[2].payload == model
    with path.open("rb") as f:
        reader = make_reader(f)
        summary = reader.get_summary()
        topics = sorted(c.topic for c in summary.channels.values())
        encodings = {c.topic: c.message_encoding for c in summary.channels.values()}
        assert summary.chunk_indexes
    assert topics == ["robocal/c/r/joints", "robocal/c/r/model", "robocal/c/r/tracker"]
    assert encodings["robocal/c/r/model"] == "robocal-model"
    assert encodings["robocal/c/r/joints"] == "json"
    samples = list(recorded_samples(path))
    assert [type(s).__name__ for _, s in samples] == ["TrackerSample", "JointSample"]


def test_killed_recorder_leaves_a_readable_file(tmp_path):
    path = tmp_path / "killed.mcap"
    proc = subprocess.Popen(
        [sys.executable, "-c", RECORDER_SCRIPT, str(path)], stdout=subprocess.PIPE, text=True
    )
    assert proc.stdout.readline().strip() == "ready"
    time.sleep(0.3)
    proc.send_signal(signal.SIGKILL)
    proc.wait(10)
    got = list(read_mcap(path))
    assert len(got) >= 500
    seqs = [int(r.payload.split(b'"seq":')[1].split(b",")[0]) for r in got]
    assert seqs == list(range(len(seqs)))


@pytest.mark.integration
def test_replay_to_bus_keeps_order_and_speed(tmp_path):
    path = tmp_path / "r.mcap"
    rec = McapRecorder(path)
    for i in range(20):  # log times 0 .. 0.95 s
        rec.add(
            "robocal/c/r/joints",
            encode(JointSample(seq=i, t=i * 0.05, q=(0.0,) * 6)),
            log_time_ns=i * 50_000_000,
        )
    rec.add("robocal/c/r/metrics", b"{}", log_time_ns=10)
    rec.close()
    port = free_port()
    a = open_session(BusConfig.loopback(port, listen=True))
    b = open_session(BusConfig.loopback(port, listen=False))
    got = []
    sub = a.declare_subscriber("robocal/**", lambda s: got.append(s.payload.to_bytes()))
    time.sleep(0.3)
    start = time.perf_counter()
    assert replay_to_bus(path, b, speed=4.0) == 20  # source streams only
    elapsed = time.perf_counter() - start
    time.sleep(0.2)
    b.close()
    assert 0.95 / 4.0 <= elapsed < 0.95 / 4.0 + 0.5
    assert [json.loads(g)["seq"] for g in got] == list(range(20))
    got.clear()
    argv = ["replay", str(path), "--connect", f"tcp/127.0.0.1:{port}", "--json"]
    assert main(argv) == 0
    time.sleep(0.2)
    sub.undeclare()
    a.close()
    assert [json.loads(g)["seq"] for g in got] == list(range(20))
