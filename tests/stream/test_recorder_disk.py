"""The recorder on a full disk with ``on_disk_full = "wait"`` (issue 19): the part being
written is closed as it is (readable up to its last flush), what arrives meanwhile is counted
``unwritable``, and once the disk has room a new part takes the later messages. A 2 MB tmpfs
on a real Zenoh loopback; needs root (mount), skipped with the reason otherwise."""

import time

import pytest

from stream.bus import BusConfig, free_port, open_session
from stream.mcap_io import RecordingReader
from stream.stages import stage_class
from tests.stream.conftest import fill, wait_for
from wire import JointSample, encode, key

pytestmark = pytest.mark.integration
CELL = "disk"


def test_recorder_waits_on_a_full_disk_and_resumes_in_a_new_part(small_fs):
    port = free_port()
    server = open_session(BusConfig.loopback(port, listen=True))
    client = open_session(BusConfig.loopback(port, listen=False))
    seq = iter(range(10**6))

    def send(n: int) -> None:
        for _ in range(n):
            i = next(seq)
            sample = JointSample(seq=i, t=float(i), q=(0.1,) * 6)
            client.put(key(CELL, "r1", "joints"), encode(sample))

    def send_until(done, timeout_s: float = 30.0) -> bool:
        """Send 10 samples at a time until ``done()`` (the subscription may still be on its
        way to the client when the first ones go out)."""
        deadline = time.monotonic() + timeout_s
        while not done() and time.monotonic() < deadline:
            send(10)
            time.sleep(0.1)
        return done()

    try:
        time.sleep(0.5)
        stage = stage_class("recorder")(server, CELL, small_fs / "rec.mcap", 0.1)
        stage.on_disk_full, stage.retry_s = "wait", 0.2
        assert send_until(lambda: stage.counter.accepted >= 50)
        time.sleep(0.5)  # flushed
        filler = fill(small_fs)
        while not stage.counter.dropped.get("unwritable"):
            send(200)
            time.sleep(0.2)
        assert stage.failure is None  # waiting, not dead
        first = stage.recorder.paths[0]
        filler.unlink()
        accepted = stage.counter.accepted
        assert wait_for(lambda: len(stage.recorder.paths) >= 2, 30), "no new part"
        assert send_until(lambda: stage.counter.accepted >= accepted + 30)
        assert stage.close() is None
    finally:
        client.close()
        server.close()
    kept = list(RecordingReader(first).messages())
    assert len(kept) >= 50  # the part cut by the full disk reads up to its last flush
    # a part opened while a few kB were still free may be cut too: the last one is whole
    last = RecordingReader(stage.recorder.paths[-1])
    later = list(last.messages())
    assert last.finished and len(later) >= 30
    dropped = stage.counter.dropped["unwritable"]
    parts = len(stage.recorder.paths)
    print(f"\nfull disk: {len(kept)} kept in part 1, {dropped} unwritable, {len(later)} in {parts}")
