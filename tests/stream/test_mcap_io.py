"""MCAP record/replay: channels and times, parts that never overwrite, metadata, constant
memory, a SIGKILLed recorder read up to its last flush, and replay with topics, times and loops."""

import contextlib
import json
import signal
import subprocess
import sys
import threading
import time
import tracemalloc

import numpy as np
import pytest
from mcap.exceptions import McapError
from mcap.reader import NonSeekingReader, make_reader
from mcap.writer import Writer

from kinematics.description import load_description
from stream.bus import BusConfig, free_port, open_session
from stream.cli import main
from stream.config import RobotConfig
from stream.mcap_io import (
    CHUNK_BYTES,
    FILE_METADATA,
    McapRecorder,
    RecordingReader,
    read_mcap,
    recorded_samples,
)
from stream.replay import ReplayOptions, replay_to_bus
from stream.stages.recorder_stage import ROBOT_METADATA, RecorderStage
from stream.trust import description_hash
from wire import JointSample, ModelHeader, TrackerSample, encode, encode_model

RECORDER_SCRIPT = """
import sys, time
from stream.mcap_io import McapRecorder
from wire import JointSample, encode
r = McapRecorder(sys.argv[1], flush_interval_s=3600)
i = 0
while True:
    r.add("robocal/c/r/joints", encode(JointSample(seq=i, t=i * 0.008, q=(0.0,) * 6)))
    i += 1
    if i % 200 == 0:
        r.flush()
        print("flushed", i, flush=True)
    time.sleep(0.0002)
"""


def joint(i: int, t: float | None = None) -> bytes:
    return encode(JointSample(seq=i, t=i * 0.05 if t is None else t, q=(0.1 * (i % 7),) * 6))


def seqs(records) -> list[int]:
    return [json.loads(r.payload)["seq"] for r in records]


def test_record_and_read_back(tmp_path):
    path = tmp_path / "rec.mcap"
    rec = McapRecorder(path)
    joint0 = encode(JointSample(seq=0, t=2.5, q=(0.0,) * 6))
    rec.add("robocal/c/r/joints", joint0, log_time_ns=2_000)
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
    assert got[1].payload == joint0 and got[2].payload == model
    with path.open("rb") as f:
        reader = make_reader(f)
        summary = reader.get_summary()
        topics = sorted(c.topic for c in summary.channels.values())
        encodings = {c.topic: c.message_encoding for c in summary.channels.values()}
        assert summary.chunk_indexes
        meta = {m.name: m.metadata for m in reader.iter_metadata()}
    assert topics == ["robocal/c/r/joints", "robocal/c/r/model", "robocal/c/r/tracker"]
    assert encodings["robocal/c/r/model"] == "robocal-model"
    assert encodings["robocal/c/r/joints"] == "json"
    assert meta[FILE_METADATA]["part"] == "1" and meta[FILE_METADATA]["robocal_version"]
    samples = list(recorded_samples(path))
    assert [type(s).__name__ for _, s in samples] == ["TrackerSample", "JointSample"]


def test_a_start_never_overwrites_and_parts_split_by_size_and_time(tmp_path):
    path = tmp_path / "rec.mcap"
    path.write_bytes(b"an earlier recording")
    rec = McapRecorder(path, flush_interval_s=0.0, split_bytes=6_000)
    for i in range(400):
        rec.add("robocal/c/r/joints", joint(i), log_time_ns=i * 1_000_000)
    rec.close()
    assert path.read_bytes() == b"an earlier recording"
    assert rec.paths[0] == tmp_path / "rec.1.mcap" and len(rec.paths) >= 3
    # a part ends at the first message past the size (its footer and summary after it)
    assert all(6_000 <= p.stat().st_size < 12_000 for p in rec.paths[:-1])
    readers = [RecordingReader(p) for p in rec.paths]
    assert all(r.finished for r in readers)  # every closed part has its footer
    meta = [dict(r.metadata())[FILE_METADATA] for r in readers]
    assert [m["part"] for m in meta] == [str(k) for k in range(1, len(rec.paths) + 1)]
    assert [m["previous"] for m in meta] == ["", *(p.name for p in rec.paths[:-1])]
    assert [s for r in readers for s in seqs(r.messages())] == list(range(400))

    timed = McapRecorder(tmp_path / "timed.mcap", split_interval_s=0.2)
    timed.add("robocal/c/r/joints", joint(0))
    time.sleep(0.3)
    timed.add("robocal/c/r/joints", joint(1))  # past the interval: this one opens part 2
    timed.add("robocal/c/r/joints", joint(2))
    timed.close()
    assert [seqs(RecordingReader(p).messages()) for p in timed.paths] == [[0], [1, 2]]


def test_reading_holds_one_chunk_not_the_file(tmp_path):
    """tracemalloc's peak while iterating stays far below what the messages add up to."""
    path = tmp_path / "big.mcap"
    rng = np.random.default_rng(0)
    with path.open("wb") as f:  # the recorder's layout, written fast with mcap's own writer
        writer = Writer(f, chunk_size=CHUNK_BYTES)
        writer.start()
        channel = writer.register_channel("robocal/c/r/joints", "json", 0)
        for i in range(20_000):
            q, qs = rng.uniform(-3, 3, 6).tolist(), rng.uniform(-3, 3, 6).tolist()
            payload = json.dumps({"seq": i, "t": i * 0.008, "q": q, "qs": qs}).encode()
            writer.add_message(channel, i * 8_000_000, payload, i * 8_000_000)
        writer.finish()
    n = total = 0
    tracemalloc.start()
    for r in read_mcap(path):
        n += 1
        total += len(r.payload)
    peak = tracemalloc.get_traced_memory()[1]
    tracemalloc.stop()
    assert n == 20_000 and total > 5_000_000
    assert peak < 2_500_000, f"peak {peak} B while reading {total} B of messages"


def test_a_killed_recorder_is_read_up_to_its_last_flush(tmp_path, capsys):
    path = tmp_path / "killed.mcap"
    proc = subprocess.Popen(
        [sys.executable, "-c", RECORDER_SCRIPT, str(path)], stdout=subprocess.PIPE, text=True
    )
    try:
        for line in proc.stdout:
            if int(line.split()[1]) >= 1000:
                break
    finally:
        proc.send_signal(signal.SIGKILL)
        proc.wait(30)
    flushed = max([1000, *(int(line.split()[1]) for line in proc.stdout)])
    reader = RecordingReader(path)
    assert not reader.finished
    got = list(reader.messages())
    assert reader.truncated  # no footer: the file ends in a torn or missing record
    assert len(got) >= flushed and seqs(got) == list(range(len(got)))
    mcap_seqs = []  # mcap's own reader, front to back, agrees up to where the file is torn
    with path.open("rb") as f, contextlib.suppress(McapError, EOFError):
        for _, _, msg in NonSeekingReader(f).iter_messages(log_time_order=False):
            mcap_seqs.append(json.loads(msg.data)["seq"])
    assert mcap_seqs == seqs(got)
    capsys.readouterr()
    argv = ["replay", str(path), "--connect", f"tcp/127.0.0.1:{free_port()}", "--json"]
    argv += ["--wait-subscribers", "0.2"]  # nobody listens: replayed anyway, and said
    assert main(argv) == 0  # robocal replay takes the unfinished file and says so
    out = json.loads(capsys.readouterr().out)
    assert out["published"] == len(got) and out["truncated"] == [str(path)]
    assert out["unheard"] == ["robocal/c/r/joints"]


def test_a_recording_cut_at_any_byte_reads_as_its_whole_chunks(tmp_path):
    path = tmp_path / "full.mcap"
    rec = McapRecorder(path, flush_interval_s=3600)
    for i in range(600):
        rec.add("robocal/c/r/joints", joint(i), log_time_ns=i)
        if i % 100 == 99:
            rec.flush()
    rec.close()
    data = path.read_bytes()
    cut = tmp_path / "cut.mcap"
    counts = set()
    for end in range(8, len(data), 89):
        cut.write_bytes(data[:end])
        got = seqs(RecordingReader(cut).messages())
        assert got == list(range(len(got)))
        counts.add(len(got))
    assert counts == {0, 100, 200, 300, 400, 500, 600}


@pytest.mark.integration
def test_the_recorder_stage_writes_robot_metadata(tmp_path):
    port = free_port()
    a = open_session(BusConfig.loopback(port, listen=True))
    T_W_0 = ((1, 0, 0, 1.5), (0, 1, 0, 0), (0, 0, 1, 0), (0, 0, 0, 1))
    robots = [RobotConfig(name="r1", description="ur10", T_W_0=T_W_0)]
    stage = RecorderStage(a, "c", tmp_path / "cell.mcap", 0.1, robots=robots)
    b = open_session(BusConfig.loopback(port, listen=False))
    time.sleep(0.3)
    for i in range(5):
        b.put("robocal/c/r1/joints", joint(i))

    def joints_on_disk() -> list[int]:  # the stage also records its own diagnostics
        return seqs(RecordingReader(stage.recorder.path).messages(lambda k: k.endswith("/joints")))

    deadline = time.monotonic() + 10
    while len(joints_on_disk()) < 5 and time.monotonic() < deadline:
        time.sleep(0.05)
    assert stage.close() is None
    b.close()
    a.close()
    reader = RecordingReader(stage.recorder.path)
    joints = reader.messages(lambda k: k == "robocal/c/r1/joints")
    assert reader.finished and seqs(joints) == list(range(5))
    meta = dict(reader.metadata())
    robot = meta[ROBOT_METADATA]
    assert robot["robot"] == "r1" and robot["description"] == "ur10"
    assert robot["description_hash"] == description_hash(load_description("ur10"))
    assert json.loads(robot["T_W_0"]) == [list(map(float, row)) for row in T_W_0]
    assert np.asarray(json.loads(robot["T_6_S"])).shape == (4, 4)


@pytest.mark.integration
def test_replay_keeps_order_speed_topics_times_and_loops(tmp_path):
    path = tmp_path / "r.mcap"
    rec = McapRecorder(path, 0.0, split_bytes=2_000)  # several parts, replayed as one
    for i in range(20):  # log times 0 .. 0.95 s
        rec.add("robocal/c/r/joints", joint(i), log_time_ns=i * 50_000_000)
        rec.add("robocal/c/r/tracker", joint(i), log_time_ns=i * 50_000_000 + 1)
    rec.add("robocal/c/r/metrics", b"{}", log_time_ns=10**9)
    rec.close()
    assert len(rec.paths) > 1
    port = free_port()
    a = open_session(BusConfig.loopback(port, listen=True))
    b = open_session(BusConfig.loopback(port, listen=False))
    got = []
    sub = a.declare_subscriber(
        "robocal/**", lambda s: got.append((str(s.key_expr), s.payload.to_bytes()))
    )
    time.sleep(0.3)

    def run(**options):
        got.clear()
        start = time.perf_counter()
        result = replay_to_bus(rec.paths, b, options=ReplayOptions(**options))
        elapsed = time.perf_counter() - start
        time.sleep(0.3)
        return result, elapsed, [(k.rsplit("/", 1)[1], json.loads(p)) for k, p in got]

    result, elapsed, msgs = run(speed=4.0, topics=("joints",))
    assert result.published == 20 and result.by_stream == {"joints": 20}
    assert 0.95 / 4.0 <= elapsed < 0.95 / 4.0 + 2.0
    assert [m["seq"] for _, m in msgs] == list(range(20))

    result, _, msgs = run(start_s=0.25, end_s=0.5)  # source streams, [0.25, 0.5) s
    assert [(s, m["seq"]) for s, m in msgs] == [
        (s, i) for i in range(5, 10) for s in ("joints", "tracker")
    ]

    result, _, msgs = run(topics=("robocal/c/r/joints",), loops=2)
    assert result.passes == 2 and [m["seq"] for _, m in msgs] == list(range(40))
    span = 19 * 0.05 + 1.0
    assert [m["t"] for _, m in msgs[20:]] == pytest.approx([i * 0.05 + span for i in range(20)])

    got.clear()
    argv = [
        "replay",
        *map(str, rec.paths),
        "--topics",
        "tracker",
        "--connect",
        f"tcp/127.0.0.1:{port}",
        "--json",
    ]
    assert main(argv) == 0
    time.sleep(0.3)
    sub.undeclare()
    b.close()
    a.close()
    assert [json.loads(p)["seq"] for _, p in got] == list(range(20))


@pytest.mark.integration
def test_a_replay_started_before_its_subscriber_loses_nothing(tmp_path):
    path = tmp_path / "r.mcap"
    rec = McapRecorder(path)
    for i in range(200):
        rec.add("robocal/c/r/joints", joint(i), log_time_ns=i)
    rec.close()
    port = free_port()
    a = open_session(BusConfig.loopback(port, listen=True))
    b = open_session(BusConfig.loopback(port, listen=False))
    done = []
    replay = threading.Thread(target=lambda: done.append(replay_to_bus(path, b)), daemon=True)
    replay.start()
    time.sleep(1.0)  # as fast as possible, all 200 would be gone by now
    got = []
    a.declare_subscriber("robocal/**", lambda s: got.append(json.loads(s.payload.to_bytes())))
    replay.join(30)
    deadline = time.monotonic() + 10
    while len(got) < 200 and time.monotonic() < deadline:
        time.sleep(0.05)
    b.close()
    a.close()
    assert done[0].unheard == [] and [m["seq"] for m in got] == list(range(200))


@pytest.mark.parametrize(
    "argv, message",
    [
        (["--speed", "0"], "speed must be > 0"),
        (["--start", "5", "--end", "2"], "must be after start"),
        (["--topics", ","], "at least one topic"),
    ],
)
def test_replay_refuses_bad_options_in_one_line(argv, message, tmp_path, capsys):
    path = tmp_path / "r.mcap"
    McapRecorder(path).close()
    assert main(["replay", str(path), *argv]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and message in err[0]


def test_replay_of_a_file_that_is_not_mcap_is_one_line(tmp_path, capsys):
    path = tmp_path / "x.mcap"
    path.write_text("hello")
    assert main(["replay", str(path), str(tmp_path / "missing.mcap")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "not an MCAP file" in err[0]
