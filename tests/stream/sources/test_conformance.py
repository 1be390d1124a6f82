"""One conformance test over every source kind: built from its ``[[sources]]`` config as the
daemon builds it, fed by a real device (a Zenoh router with a ROS 2 node, an asyncua server,
a dataset file, the simulator), it starts, publishes well-formed messages that decode with the
project's schemas, counts what it could not deliver, and stops within a bound."""

from __future__ import annotations

import io
import math
import threading
import time
from contextlib import contextmanager

import pytest

from kinematics.dataset import read_dataset, write_dataset
from kinematics.description import load_description
from stream.bus import free_port
from stream.log import JsonLogger
from stream.sources.build import SourceThread, build_source
from stream.sources.config import (
    DatasetSourceConfig,
    OpcUaSourceConfig,
    Ros2SourceConfig,
    SimSourceConfig,
)
from stream.sources.ros2 import JOINT_TYPE
from tests.stream.sources.conftest import CELL, ROBOT, RosCell
from wire import Diagnostics, decode

pytestmark = pytest.mark.integration

STOP_BOUND_S = 10.0  # the daemon's shutdown budget is 7 s + 1.5 s
NAMES = tuple(f"joint_{i}" for i in range(1, 7))


@contextmanager
def ros_device():
    """A ROS 2 node streaming joint states (50 Hz) and tracker poses (5 Hz), one payload
    of garbage among them (its one undeliverable sample)."""
    port = free_port()
    cell = RosCell(port)
    stop = threading.Event()

    def node() -> None:
        time.sleep(1.0)  # the source's subscriptions reach the router
        cell.publish("/joint_states", JOINT_TYPE, b"\x00\x01\x00\x00not a JointState")
        k = 0
        while not stop.is_set():
            t = 50.0 + 0.02 * k
            cell.publish("/joint_states", JOINT_TYPE, cell.joint_state(t, list(NAMES), [0.1] * 6))
            if k % 10 == 0:
                quat = (0.0, 0.0, math.sin(0.1), math.cos(0.1))
                payload = cell.pose(t, (1.0, 0.5, 1.2), quat)
                cell.publish("/tracker/pose", "geometry_msgs/msg/PoseStamped", payload)
            k += 1
            time.sleep(0.02)

    thread = threading.Thread(target=node, daemon=True)
    thread.start()
    try:
        yield Ros2SourceConfig(connect=(f"tcp/127.0.0.1:{port}",), joint_names=NAMES)
    finally:
        stop.set()
        thread.join(5.0)
        cell.close()


@contextmanager
def opcua_device(server):
    """The asyncua server; one channel reports a failed sensor for a while."""
    cfg = OpcUaSourceConfig(url=server.url, nodes=server.node_ids, period_s=0.1)

    def fail_once() -> None:
        time.sleep(0.5)
        server.write("j1_gear", 0.0, good=False)
        time.sleep(0.5)
        server.write("j1_gear", 21.0)

    thread = threading.Thread(target=fail_once, daemon=True)
    thread.start()
    try:
        yield cfg
    finally:
        thread.join(10.0)


@contextmanager
def dataset_device(dataset_file, tmp_path):
    """The campaign file with one thermometer reading 160 °C (beyond the schema's range)."""
    ds = read_dataset(dataset_file)
    ds.table.loc[10, "temp_base"] = 160.0
    path = write_dataset(ds, tmp_path / "hot.parquet")
    yield DatasetSourceConfig(path=str(path), speed=0, joint_rate_hz=25.0)


KINDS = {
    "sim": ({"joints", "tracker", "temperature"}, None),
    "dataset": ({"joints", "tracker", "temperature"}, "out_of_range"),
    "ros2": ({"joints", "tracker"}, "decode"),
    "opcua": ({"temperature"}, "bad_value"),
}


@pytest.mark.parametrize("kind", sorted(KINDS))
def test_source_conformance(kind, bus, opcua_server, dataset_file, tmp_path):
    session, collector = bus
    streams, reason = KINDS[kind]
    devices = {
        "sim": lambda: _just(SimSourceConfig(n=12, speed=0)),
        "dataset": lambda: dataset_device(dataset_file, tmp_path),
        "ros2": ros_device,
        "opcua": lambda: opcua_device(opcua_server),
    }
    with devices[kind]() as cfg:
        source = build_source(cfg, session, CELL, ROBOT, load_description(ROBOT))
        assert source.kind == kind
        thread = SourceThread(source, JsonLogger(stream=io.StringIO())).start()
        try:
            for stream in streams:
                assert len(collector.wait(stream, 5)) >= 5, f"{kind}: too few {stream} samples"
            deadline = time.monotonic() + 30
            while reason and not source.counter.dropped[reason] and time.monotonic() < deadline:
                time.sleep(0.05)
        finally:
            start = time.monotonic()
            error = thread.close(timeout_s=STOP_BOUND_S)
            stopped_in = time.monotonic() - start
    assert error is None
    assert not thread._thread.is_alive() and stopped_in < STOP_BOUND_S
    time.sleep(0.3)  # what the source published last (its final diagnostics) is in flight
    # Well-formed: every message decodes with the project's schemas, seq counts up per stream.
    published = 0
    for stream in ("joints", "tracker", "temperature"):
        msgs = collector.decoded(stream)
        assert (stream in streams) == bool(msgs), stream
        assert [m.seq for m in msgs] == sorted({m.seq for m in msgs}), stream
        published += len(msgs)
    assert published == source.published
    undelivered = dict(source.counter.dropped)
    assert (reason in undelivered) if reason else undelivered == {}
    diag = [decode(p, Diagnostics) for p in collector.raw["diagnostics"]]
    assert diag and diag[-1].stage == f"source_{kind}"
    assert (diag[-1].accepted, diag[-1].dropped) == (source.published, undelivered)


@contextmanager
def _just(cfg):
    yield cfg
