"""Load held (issue 19), the bounded part: a real window stage on loopback Zenoh flooded while
its worker is busy drops what its queue cannot hold as ``overload`` (the queue never holds more
than its byte bound), refuses 10 MB messages as ``too_large`` before copying them, counts every
sample exactly once (handled + overload == published) and lives on. Rates and peak memory of
a whole daemon: bench/load.py and bench/soak.py (BENCHMARKS.md)."""

import io
import threading

import pytest

from stream.bus import BusConfig, free_port, open_session, publisher
from stream.log import JsonLogger
from stream.stages import WindowStage
from stream.window import WindowConfig
from tests.stream.conftest import wait_for
from wire import JointSample, encode, key

pytestmark = pytest.mark.integration


@pytest.fixture
def window():
    port = free_port()
    server = open_session(BusConfig.loopback(port, listen=True))
    client = open_session(BusConfig.loopback(port, listen=False))
    cfg = WindowConfig(n_joints=6, require_temperatures=False)
    stage = WindowStage(server, "load", "r1", cfg, JsonLogger(stream=io.StringIO()))
    pub = publisher(client, key("load", "r1", "joints"))
    assert wait_for(lambda: pub.matching_status.matching)
    yield stage, pub
    stage.close(10)
    client.close()
    server.close()


def joints(i: int) -> bytes:
    return encode(JointSample(seq=i, t=1000.0 + i * 0.008, q=(0.1,) * 6))


def test_a_flood_on_a_busy_stage_is_dropped_as_overload_within_the_byte_bound(window):
    stage, pub = window
    bound = 64 * 1024
    stage.worker.max_queue_bytes = bound
    release = threading.Event()
    busy = threading.Thread(target=stage.worker.call, args=(release.wait,))
    busy.start()  # the worker is stuck in one long item
    n, peak = 5000, 0
    for i in range(n):
        pub.put(joints(i))
        peak = max(peak, stage.worker.queued_bytes)
    assert wait_for(lambda: stage.worker.overload + stage.worker.queue.qsize() >= n)
    assert peak <= bound and stage.worker.overload > 0
    release.set()
    busy.join(30)
    assert wait_for(lambda: stage.handled + stage.worker.overload == n), (stage.handled, n)
    pub.put(joints(n))  # the next sample shows the window the gap the overload left
    assert wait_for(lambda: stage.handled + stage.worker.overload == n + 1)
    stage.count_worker_drops()
    assert stage.counter.dropped["overload"] == stage.worker.overload
    assert stage.counter.dropped["missed"] == stage.worker.overload
    assert stage.failure is None and stage.worker.alive
    print(f"\noverload: {n} published, {stage.handled} handled, {stage.worker.overload} dropped "
          f"(queue peak {peak} B <= {bound} B)")  # fmt: skip


def test_10_mb_messages_are_refused_as_too_large_before_they_are_copied(window):
    stage, pub = window
    blob = b'{"schema": "robocal.joints", "pad": "' + b"x" * 10_000_000 + b'"}'
    for _ in range(5):
        pub.put(blob)
    pub.put(joints(0))
    assert wait_for(lambda: stage.worker.too_large == 5 and stage.handled == 1)
    assert stage.worker.queued_bytes == 0
    stage.count_worker_drops()
    assert stage.counter.dropped["too_large"] == 5 and stage.failure is None
