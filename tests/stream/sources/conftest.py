"""Fixtures of the source tests: a loopback robocal bus with a collector, a real Zenoh router
for the ROS 2 graph, a real asyncua server, and a small dataset file."""

from __future__ import annotations

import asyncio
import json
import threading
import time
from collections import defaultdict
from pathlib import Path

import pytest
import zenoh
from asyncua import Server, ua

from kinematics.dataset import write_dataset
from sim_sources.cell import simulate
from sim_sources.scenarios import get_scenario
from stream.bus import BusConfig, free_port, open_session
from wire import STREAM_TYPES, decode

CELL, ROBOT = "cell1", "fanuc_m900ib700"
CHANNELS = {"base": "Cell.Base", "j1_gear": "Cell.J1Gear"}


class Collector:
    """Every message under ``robocal/<cell>/<robot>/**`` seen by a second session, decoded."""

    def __init__(self, session: zenoh.Session) -> None:
        self.raw: dict[str, list[bytes]] = defaultdict(list)
        self._sub = session.declare_subscriber(f"robocal/{CELL}/{ROBOT}/**", self._on)

    def _on(self, sample: zenoh.Sample) -> None:
        self.raw[str(sample.key_expr).rsplit("/", 1)[1]].append(sample.payload.to_bytes())

    def decoded(self, stream: str) -> list:
        return [decode(p, STREAM_TYPES[stream]) for p in list(self.raw[stream])]

    def wait(self, stream: str, n: int, timeout_s: float = 30.0) -> list:
        deadline = time.monotonic() + timeout_s
        while len(self.raw[stream]) < n and time.monotonic() < deadline:
            time.sleep(0.02)
        return self.decoded(stream)


@pytest.fixture
def bus():
    """``(session the sources publish on, collector on a second session)`` over loopback."""
    port = free_port()
    pub = open_session(BusConfig.loopback(port, listen=True))
    sub = open_session(BusConfig.loopback(port, listen=False))
    collector = Collector(sub)
    time.sleep(0.3)
    yield pub, collector
    sub.close()
    pub.close()


def open_router(port: int) -> zenoh.Session:
    """A Zenoh router on ``tcp/127.0.0.1:<port>`` (as ``rmw_zenohd`` is for a ROS 2 graph)."""
    zc = zenoh.Config()
    zc.insert_json5("mode", '"router"')
    zc.insert_json5("scouting/multicast/enabled", "false")
    zc.insert_json5("listen/endpoints", json.dumps([f"tcp/127.0.0.1:{port}"]))
    return zenoh.open(zc)


def open_ros_client(port: int) -> zenoh.Session:
    """A ROS 2 node's session: a client of the router that reconnects after a loss."""
    zc = zenoh.Config()
    zc.insert_json5("mode", '"client"')
    zc.insert_json5("scouting/multicast/enabled", "false")
    zc.insert_json5("connect/endpoints", json.dumps([f"tcp/127.0.0.1:{port}"]))
    zc.insert_json5("connect/retry", '{"period_init_ms": 200, "period_max_ms": 500}')
    return zenoh.open(zc)


class OpcUaServer:
    """A real asyncua server on ``opc.tcp://127.0.0.1:<port>/`` in its own event loop thread,
    with one Double variable per temperature channel; ``stop()``/``start()`` restart it."""

    def __init__(self, port: int) -> None:
        self.url = f"opc.tcp://127.0.0.1:{port}/"
        self.loop = asyncio.new_event_loop()
        self._thread = threading.Thread(target=self.loop.run_forever, daemon=True)
        self._thread.start()
        self.vars = {}
        self.call(self._init())
        self.start()

    def call(self, coro, timeout_s: float = 60.0):
        return asyncio.run_coroutine_threadsafe(coro, self.loop).result(timeout_s)

    async def _init(self) -> None:
        self.server = Server()
        await self.server.init()
        self.server.set_endpoint(self.url)
        idx = await self.server.register_namespace("urn:robocal:test")
        obj = await self.server.nodes.objects.add_object(idx, "Cell")
        for i, (channel, name) in enumerate(CHANNELS.items()):
            node = ua.NodeId(name, idx)
            self.vars[channel] = await obj.add_variable(node, name, 20.0 + i)
        self.node_ids = {c: v.nodeid.to_string() for c, v in self.vars.items()}

    def start(self) -> None:
        self.call(self.server.start())

    def stop(self) -> None:
        self.call(self.server.stop())

    def write(self, channel: str, value: float, good: bool = True) -> None:
        status = ua.StatusCode(ua.StatusCodes.Good if good else ua.StatusCodes.BadSensorFailure)
        dv = ua.DataValue(ua.Variant(value, ua.VariantType.Double), StatusCode=status)
        self.call(self.vars[channel].write_value(dv))

    def close(self) -> None:
        try:
            self.stop()
        finally:
            self.loop.call_soon_threadsafe(self.loop.stop)
            self._thread.join(5.0)


@pytest.fixture(scope="module")
def opcua_server():
    server = OpcUaServer(free_port())
    yield server
    server.close()


@pytest.fixture(scope="module")
def dataset_file(tmp_path_factory) -> Path:
    """A 30-point simulated campaign of the Fanuc (timed rows, temperatures) as Parquet."""
    ds = simulate(get_scenario("paper"), 30, 0)
    path = tmp_path_factory.mktemp("dataset") / "campaign.parquet"
    write_dataset(ds, path)
    return path


class RosCell:
    """A ROS 2 graph as rmw_zenoh runs it: a router on loopback and a node publishing
    ``sensor_msgs/msg/JointState`` and a tracker pose as CDR (serialized by ``rosbags``) on
    rmw_zenoh's key expressions, each sample with rmw_zenoh's attachment."""

    #: A type hash in rmw_zenoh's ``RIHS01_<64 hex>`` form (the source matches any hash).
    HASH = "RIHS01_" + "5e" * 32

    def __init__(self, port: int) -> None:
        from rosbags.typesys import Stores, get_typestore

        self.port = port
        self.router = open_router(port)
        self.node = open_ros_client(port)
        self.ts = get_typestore(Stores.ROS2_HUMBLE)
        self.gid = bytes(range(16))
        self.seq = defaultdict(int)

    def header(self, t: float, frame_id: str = "tracker"):
        T = self.ts.types
        sec = int(t)
        stamp = T["builtin_interfaces/msg/Time"](sec=sec, nanosec=int(round((t - sec) * 1e9)))
        return T["std_msgs/msg/Header"](stamp=stamp, frame_id=frame_id)

    def joint_state(self, t: float, names: list[str], positions: list[float]) -> bytes:
        import numpy as np

        msg = self.ts.types["sensor_msgs/msg/JointState"](
            header=self.header(t, ""),
            name=names,
            position=np.array(positions, dtype=float),
            velocity=np.array([]),
            effort=np.array([]),
        )
        return bytes(self.ts.serialize_cdr(msg, "sensor_msgs/msg/JointState"))

    def pose(self, t: float, xyz, quat, kind: str = "PoseStamped", frame_id: str = "tracker"):
        T = self.ts.types
        if kind == "PoseStamped":
            pose = T["geometry_msgs/msg/Pose"](
                position=T["geometry_msgs/msg/Point"](x=xyz[0], y=xyz[1], z=xyz[2]),
                orientation=T["geometry_msgs/msg/Quaternion"](*quat),
            )
            msg = T["geometry_msgs/msg/PoseStamped"](header=self.header(t, frame_id), pose=pose)
        else:
            tf = T["geometry_msgs/msg/Transform"](
                translation=T["geometry_msgs/msg/Vector3"](x=xyz[0], y=xyz[1], z=xyz[2]),
                rotation=T["geometry_msgs/msg/Quaternion"](*quat),
            )
            msg = T["geometry_msgs/msg/TransformStamped"](
                header=self.header(t, frame_id), child_frame_id="probe", transform=tf
            )
        return bytes(self.ts.serialize_cdr(msg, f"geometry_msgs/msg/{kind}"))

    def publish(self, topic: str, msgtype: str, payload: bytes) -> int:
        """Put ``payload`` on the topic's key with the next sequence number; returns it."""
        from zenoh.ext import Int64, z_serialize

        from stream.sources.ros2 import topic_key

        seq = self.seq[topic]
        self.seq[topic] += 1
        att = z_serialize(
            (
                "sequence_number",
                Int64(seq),
                "source_timestamp",
                Int64(time.time_ns()),
                "source_gid",
                self.gid,
            )
        )
        self.node.put(topic_key(0, topic, msgtype, self.HASH), payload, attachment=att)
        return seq

    def close(self) -> None:
        self.node.close()
        self.router.close()
