"""The ROS 2 (rmw_zenoh) source on a real Zenoh router: CDR joint states mapped to the
description's joint order, tracker poses of both types, refusals counted, and a router that
goes away and comes back (the source resumes and counts the samples it missed)."""

from __future__ import annotations

import io
import math
import threading
import time

import pytest

from kinematics.errors import ConfigError
from stream.bus import free_port
from stream.log import JsonLogger
from stream.sources.build import SourceThread
from stream.sources.config import Ros2SourceConfig
from stream.sources.ros2 import JOINT_TYPE, Ros2Source, parse_attachment, topic_key
from tests.stream.sources.conftest import CELL, ROBOT, RosCell, open_router

pytestmark = pytest.mark.integration

NAMES = [f"joint_{i}" for i in range(1, 7)]
POSE = "geometry_msgs/msg/PoseStamped"
QUAT = (0.0, 0.0, math.sin(0.25), math.cos(0.25))


def wait_for(predicate, timeout_s: float = 30.0) -> bool:
    deadline = time.monotonic() + timeout_s
    while not predicate() and time.monotonic() < deadline:
        time.sleep(0.02)
    return predicate()


def start(session, port: int, **kw) -> SourceThread:
    cfg = Ros2SourceConfig(connect=(f"tcp/127.0.0.1:{port}",), joint_names=tuple(NAMES), **kw)
    source = Ros2Source(session, CELL, ROBOT, cfg, n_joints=6)
    return SourceThread(source, JsonLogger(stream=io.StringIO())).start()


def test_key_expressions_follow_rmw_zenoh():
    assert topic_key(0, "/joint_states", JOINT_TYPE) == (
        "0/joint_states/sensor_msgs::msg::dds_::JointState_/*"
    )
    assert topic_key(7, "/cell/tracker/pose/", POSE, "RIHS01_ab") == (
        "7/cell/tracker/pose/geometry_msgs::msg::dds_::PoseStamped_/RIHS01_ab"
    )
    assert parse_attachment(b"not an attachment") is None


def test_joint_states_and_poses_are_decoded_in_description_order(bus):
    session, collector = bus
    port = free_port()
    cell = RosCell(port)
    src = start(session, port, frame_id="tracker")
    try:
        time.sleep(1.0)  # the source's subscriptions reach the router
        # The controller lists the joints in its own order, with a gripper joint besides.
        shuffled = [NAMES[i] for i in (3, 0, 5, 1, 4, 2)] + ["gripper"]
        values = {n: 0.1 * (i + 1) for i, n in enumerate(NAMES)} | {"gripper": 0.9}
        payload = cell.joint_state(12.5, shuffled, [values[n] for n in shuffled])
        cell.publish("/joint_states", JOINT_TYPE, payload)
        cell.publish("/tracker/pose", POSE, cell.pose(12.75, (1.0, 2.0, 3.0), QUAT))
        cell.publish("/tracker/pose", POSE, cell.pose(13.0, (1.0, 2.0, 3.0), QUAT, frame_id="x"))
        cell.publish("/joint_states", JOINT_TYPE, cell.joint_state(13.0, NAMES[:5], [0.0] * 5))
        cell.publish("/joint_states", JOINT_TYPE, b"\x00\x01\x00\x00garbage")
        joints = collector.wait("joints", 1)
        poses = collector.wait("tracker", 1)
        assert wait_for(lambda: sum(src.source.counter.dropped.values()) == 3)
    finally:
        src.close()
        cell.close()
    assert [j.q for j in joints] == [tuple(0.1 * (i + 1) for i in range(6))]
    assert joints[0].t == pytest.approx(12.5)
    assert [(p.t, p.xyz, p.quat, p.frame) for p in poses] == [
        (pytest.approx(12.75), (1.0, 2.0, 3.0), QUAT, "tracker")
    ]
    assert dict(src.source.counter.dropped) == {"frame_id": 1, "joint_names": 1, "decode": 1}


def test_transform_stamped_poses(bus):
    session, collector = bus
    port = free_port()
    cell = RosCell(port)
    src = start(session, port, pose_type="TransformStamped", pose_topic="/tf_probe", frame="base")
    try:
        time.sleep(1.0)
        payload = cell.pose(3.0, (0.5, 0.0, 1.0), QUAT, kind="TransformStamped")
        cell.publish("/tf_probe", "geometry_msgs/msg/TransformStamped", payload)
        poses = collector.wait("tracker", 1)
    finally:
        src.close()
        cell.close()
    assert [(p.xyz, p.quat, p.frame) for p in poses] == [((0.5, 0.0, 1.0), QUAT, "base")]


def test_router_loss_reconnects_and_counts_what_was_missed(bus):
    """The router goes down while the node publishes; after it is back (same port), samples
    flow again, and every sequence number is either delivered or counted as missed."""
    session, collector = bus
    port = free_port()
    cell = RosCell(port)
    src = start(session, port, reconnect_s=0.2)
    sent = []
    stop = threading.Event()

    def node() -> None:  # a 50 Hz joint-state publisher
        t = 100.0
        while not stop.is_set():
            t += 0.02
            sent.append(
                cell.publish("/joint_states", JOINT_TYPE, cell.joint_state(t, NAMES, [t / 1e3] * 6))
            )
            time.sleep(0.02)

    publisher = threading.Thread(target=node, daemon=True)
    try:
        time.sleep(1.0)
        publisher.start()
        assert collector.wait("joints", 10)
        cell.router.close()  # the ROS graph's router dies ...
        time.sleep(1.0)
        before = len(collector.raw["joints"])
        cell.router = open_router(port)  # ... and is restarted on the same port
        assert wait_for(lambda: len(collector.raw["joints"]) >= before + 10), "no samples resumed"
        stop.set()
        publisher.join(5.0)
        time.sleep(0.5)
        # One more after the stream settled: its sequence number closes any trailing gap.
        sent.append(
            cell.publish("/joint_states", JOINT_TYPE, cell.joint_state(999.0, NAMES, [0.0] * 6))
        )
        assert wait_for(
            lambda: collector.raw["joints"] and collector.decoded("joints")[-1].t == 999.0
        )
    finally:
        stop.set()
        src.close()
        cell.close()
    delivered = len(collector.decoded("joints"))
    missed = src.source.counter.dropped["missed"]
    assert missed >= 1  # a second of publishing went nowhere
    assert delivered + missed == len(sent)
    assert src.source.published == delivered


def test_joint_names_must_match_the_description(bus):
    session, _ = bus
    cfg = Ros2SourceConfig(joint_names=("a", "b"))
    with pytest.raises(ConfigError, match="lists 2 joints, robot 'fanuc_m900ib700' has 6"):
        Ros2Source(session, CELL, ROBOT, cfg, n_joints=6)


def test_a_router_that_is_not_up_yet_is_waited_for(bus):
    session, collector = bus
    port = free_port()
    src = start(session, port, reconnect_s=0.2)
    try:
        assert wait_for(lambda: src.source.connect_attempts >= 2)  # no router: it keeps trying
        assert "connection" in src.source.counter.refused
        cell = RosCell(port)
        try:
            time.sleep(1.0)
            cell.publish("/joint_states", JOINT_TYPE, cell.joint_state(1.0, NAMES, [0.2] * 6))
            joints = collector.wait("joints", 1)
        finally:
            cell.close()
    finally:
        src.close()
    assert [j.q for j in joints] == [(0.2,) * 6]
