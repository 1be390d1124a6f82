"""ROS 2 over Zenoh (rmw_zenoh): joint states and tracker poses from a ROS 2 graph.

rmw_zenoh publishes a topic on the key expression ``<domain_id>/<topic without leading and
trailing '/'>/<package>::msg::dds_::<Type>_/<type hash>`` (``RIHS01_<hex>``; Humble builds
have no hash), the payload in CDR with its encapsulation header, and an attachment (Zenoh's
serializer) with ``sequence_number``, ``source_timestamp`` (ns) and ``source_gid``. This source
subscribes with a wildcard for the hash, decodes with ``rosbags`` (Humble message definitions;
JointState, PoseStamped and TransformStamped are unchanged in later releases), maps the
JointState's names to the description's joint order (``joint_names``) and publishes
``JointSample`` (``t`` = header stamp, s) and ``TrackerSample`` (in ``frame``).

The ROS session is a Zenoh client of the graph's router: while the router is down the
session keeps reconnecting and re-declares the subscriptions when it is back. Nothing is
delivered meanwhile; a gap in a publisher's sequence numbers counts the samples it missed
(``missed``), as do payloads it cannot decode (``decode``), JointStates without the configured
joints (``joint_names``), poses in another ``frame_id`` and a full queue (``overflow``).
"""

from __future__ import annotations

import json
import queue
import time
from typing import Any

import zenoh
from rosbags.typesys import Stores, get_typestore
from zenoh.ext import Int64, z_deserialize

from kinematics.errors import ConfigError
from stream.sources._base import Source
from stream.sources.config import Ros2SourceConfig
from wire import JointSample, TrackerSample

JOINT_TYPE = "sensor_msgs/msg/JointState"
POSE_TYPES = {
    "PoseStamped": "geometry_msgs/msg/PoseStamped",
    "TransformStamped": "geometry_msgs/msg/TransformStamped",
}
_ATTACHMENT = tuple[str, Int64, str, Int64, str, bytes]


def dds_type_name(msgtype: str) -> str:
    """rmw_zenoh's type chunk of a ROS message type (its DDS name).

    >>> dds_type_name("geometry_msgs/msg/PoseStamped")
    'geometry_msgs::msg::dds_::PoseStamped_'
    """
    package, kind, name = msgtype.split("/")
    return f"{package}::{kind}::dds_::{name}_"


def topic_key(domain_id: int, topic: str, msgtype: str, type_hash: str = "*") -> str:
    """The key expression rmw_zenoh publishes ``topic`` of ``msgtype`` on (any hash by default).

    >>> topic_key(0, "/joint_states", "sensor_msgs/msg/JointState")
    '0/joint_states/sensor_msgs::msg::dds_::JointState_/*'
    """
    return f"{domain_id}/{topic.strip('/')}/{dds_type_name(msgtype)}/{type_hash}"


def parse_attachment(raw: bytes | None) -> tuple[int, int, bytes] | None:
    """``(sequence_number, source_timestamp_ns, source_gid)`` of an rmw_zenoh attachment."""
    if raw is None:
        return None
    try:
        k1, seq, k2, stamp, k3, gid = z_deserialize(_ATTACHMENT, zenoh.ZBytes(raw))
    except Exception:  # noqa: BLE001 - another format: no gap detection for this sample
        return None
    if (k1, k2, k3) != ("sequence_number", "source_timestamp", "source_gid"):
        return None
    return int(seq), int(stamp), bytes(gid)


def open_ros_session(cfg: Ros2SourceConfig) -> zenoh.Session:
    """A Zenoh client of the ROS graph's router that reconnects on its own after a loss."""
    zc = zenoh.Config()
    zc.insert_json5("mode", '"client"')
    zc.insert_json5("scouting/multicast/enabled", "false")
    zc.insert_json5("connect/endpoints", json.dumps(list(cfg.connect)))
    period_ms = int(cfg.reconnect_s * 1000)
    zc.insert_json5(
        "connect/retry",
        json.dumps({"period_init_ms": period_ms, "period_max_ms": 4 * period_ms}),
    )
    return zenoh.open(zc)


class Ros2Source(Source):
    """Joint states and tracker poses of a ROS 2 (rmw_zenoh) graph (module docstring)."""

    kind = "ros2"

    def __init__(
        self,
        session: zenoh.Session,
        cell: str,
        robot: str,
        cfg: Ros2SourceConfig,
        n_joints: int,
    ) -> None:
        if len(cfg.joint_names) != n_joints:
            raise ConfigError(
                f"sources.joint_names lists {len(cfg.joint_names)} joints, robot {robot!r} "
                f"has {n_joints}"
            )
        super().__init__(session, cell, robot)
        self.cfg = cfg
        self.typestore = get_typestore(Stores.ROS2_HUMBLE)
        self._queue: queue.Queue[tuple[str, bytes, bytes | None, float]] = queue.Queue(
            cfg.max_queue
        )
        self._ros: zenoh.Session | None = None
        self._subs: list[Any] = []
        self._last: dict[tuple[str, bytes], int] = {}
        self._seq = {"joints": 0, "tracker": 0}
        self.connect_attempts = 0

    def keys(self) -> dict[str, str]:
        """The key expression of each stream (any type hash)."""
        cfg = self.cfg
        return {
            "joints": topic_key(cfg.domain_id, cfg.joint_topic, JOINT_TYPE),
            "tracker": topic_key(cfg.domain_id, cfg.pose_topic, POSE_TYPES[cfg.pose_type]),
        }

    def _callback(self, stream: str):
        def enqueue(sample: zenoh.Sample) -> None:
            att = sample.attachment
            item = (stream, sample.payload.to_bytes(), att and att.to_bytes(), time.time())
            try:
                self._queue.put_nowait(item)
            except queue.Full:
                self.undelivered("overflow")

        return enqueue

    def _connect(self) -> bool:
        """Open the ROS session and subscribe; False (counted) while the router is away."""
        self.connect_attempts += 1
        try:
            self._ros = open_ros_session(self.cfg)
        except zenoh.ZError as exc:
            with self._lock:
                self.counter.refused["connection"] = f"{list(self.cfg.connect)}: {exc}"[:300]
            return False
        for stream, k in self.keys().items():
            self._subs.append(self._ros.declare_subscriber(k, self._callback(stream)))
        return True

    def run(self) -> None:
        while self.running and not self._connect():
            self.wait(self.cfg.reconnect_s)
        while self.running:
            try:
                item = self._queue.get(timeout=0.1)
            except queue.Empty:
                continue
            self.handle(*item)

    def handle(self, stream: str, payload: bytes, attachment: bytes | None, now: float) -> None:
        """Decode one ROS message and publish it (or count why not)."""
        meta = parse_attachment(attachment)
        if meta is not None:
            self._count_gap(stream, meta[0], meta[2])
        try:
            if stream == "joints":
                sample = self._joints(payload, meta, now)
            else:
                sample = self._pose(payload, meta, now)
        except Exception:  # noqa: BLE001 - any decoding failure of a foreign payload
            self.undelivered("decode")
            return
        if sample is not None:
            self.publish(sample)

    def _count_gap(self, stream: str, seq: int, gid: bytes) -> None:
        last = self._last.get((stream, gid))
        if last is not None and seq > last + 1:
            self.undelivered("missed", seq - last - 1)
        self._last[(stream, gid)] = seq  # a lower one: the publisher restarted

    def _stamp(self, header: Any, meta: tuple[int, int, bytes] | None, now: float) -> float:
        t = header.stamp.sec + header.stamp.nanosec * 1e-9
        if t > 0:
            return t
        return meta[1] * 1e-9 if meta is not None and meta[1] > 0 else now

    def _next(self, stream: str) -> int:
        self._seq[stream] += 1
        return self._seq[stream] - 1

    def _joints(self, payload: bytes, meta: Any, now: float) -> JointSample | None:
        msg = self.typestore.deserialize_cdr(payload, JOINT_TYPE)
        names = list(msg.name)
        if len(msg.position) != len(names):
            self.undelivered("malformed")
            return None
        try:
            idx = [names.index(n) for n in self.cfg.joint_names]
        except ValueError:
            self.undelivered("joint_names")
            return None
        q = tuple(float(msg.position[i]) for i in idx)
        return JointSample(seq=self._next("joints"), t=self._stamp(msg.header, meta, now), q=q)

    def _pose(self, payload: bytes, meta: Any, now: float) -> TrackerSample | None:
        msg = self.typestore.deserialize_cdr(payload, POSE_TYPES[self.cfg.pose_type])
        if self.cfg.frame_id and msg.header.frame_id != self.cfg.frame_id:
            self.undelivered("frame_id")
            return None
        if self.cfg.pose_type == "PoseStamped":
            p, r = msg.pose.position, msg.pose.orientation
        else:
            p, r = msg.transform.translation, msg.transform.rotation
        return TrackerSample(
            seq=self._next("tracker"),
            t=self._stamp(msg.header, meta, now),
            xyz=(float(p.x), float(p.y), float(p.z)),
            quat=(float(r.x), float(r.y), float(r.z), float(r.w)),
            frame=self.cfg.frame,
        )

    def cleanup(self, failed: bool) -> None:
        for sub in self._subs:
            sub.undeclare()
        self._subs.clear()
        if self._ros is not None:
            self._ros.close()
            self._ros = None
