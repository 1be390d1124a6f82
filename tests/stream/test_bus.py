"""Zenoh sessions on loopback: delivery through worker queues, liveliness, config checks."""

import socket
import threading
import time

import pytest

from kinematics.errors import ConfigError
from stream.bus import (
    BusConfig,
    alive_stages,
    declare_alive,
    ephemeral_range,
    free_port,
    open_session,
    publisher,
)
from stream.worker import Worker, subscribe


def test_free_ports_lie_outside_the_ephemeral_range_and_can_be_bound():
    """An outgoing connection never takes them before the caller listens (ports handed out by
    a bind to 0 lie inside the range, and one was taken so in CI)."""
    ports = {free_port() for _ in range(20)}
    low, high = ephemeral_range()
    assert len(ports) > 1 and all(not low <= p <= high for p in ports)
    for port in ports:
        with socket.socket() as s:
            s.bind(("127.0.0.1", port))


@pytest.fixture
def pair():
    port = free_port()
    a = open_session(BusConfig.loopback(port, listen=True))
    b = open_session(BusConfig.loopback(port, listen=False))
    time.sleep(0.3)
    yield a, b
    b.close()
    a.close()


@pytest.mark.integration
def test_worker_handles_every_sample_in_order_off_the_zenoh_thread(pair):
    a, b = pair
    seen, threads = [], set()

    def handle(item):
        seen.append(item.payload)
        threads.add(threading.current_thread().name)

    worker = Worker("test-worker", handle)
    sub = subscribe(a, "robocal/c/r/joints", worker)
    time.sleep(0.2)
    pub = publisher(b, "robocal/c/r/joints")
    for i in range(2000):
        pub.put(str(i).encode(), attachment=b"meta")
    deadline = time.monotonic() + 10
    while len(seen) < 2000 and time.monotonic() < deadline:
        time.sleep(0.01)
    assert worker.drain(5.0)
    assert seen == [str(i).encode() for i in range(2000)]
    assert threads == {"test-worker"}
    sub.undeclare()
    worker.stop()


@pytest.mark.integration
def test_liveliness_tokens_come_and_go(pair):
    a, b = pair
    token = declare_alive(a, "c", "r", "window")
    time.sleep(0.2)
    assert alive_stages(b, "c") == ["robocal/c/r/alive/window"]
    token.undeclare()
    time.sleep(0.2)
    assert alive_stages(b, "c") == []


def test_worker_call_runs_after_queued_items():
    order = []
    worker = Worker("w", lambda item: order.append(item))
    worker.queue.put("a")
    worker.call(lambda: order.append("call"))
    worker.stop()
    assert order == ["a", "call"]


@pytest.mark.parametrize(
    "kwargs, match",
    [
        ({"mode": "broker"}, "bus.mode"),
        ({"listen": ("127.0.0.1:7447",)}, "endpoint"),
        ({"mode": "client", "multicast_scouting": False}, "client"),
    ],
)
def test_bad_bus_config(kwargs, match):
    with pytest.raises(ConfigError, match=match):
        BusConfig(**kwargs)
