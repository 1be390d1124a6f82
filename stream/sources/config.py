"""Source settings of the daemon TOML (``[[sources]]``): one small frozen dataclass per kind.

>>> source_class({"kind": "opcua"}).__name__
'OpcUaSourceConfig'
>>> OpcUaSourceConfig(url="opc.tcp://127.0.0.1:4840", nodes={"ambient": "ns=2;i=2"}).nodes
(('ambient', 'ns=2;i=2'),)
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace
from typing import Any

from kinematics.errors import ConfigError

POSE_TYPES = ("PoseStamped", "TransformStamped")
FRAMES = ("base", "tracker")


def _positive(**values: float) -> None:
    for name, value in values.items():
        if not (isinstance(value, int | float) and math.isfinite(value) and value > 0):
            raise ConfigError(f"{name} must be a number > 0, got {value!r}")


def _non_negative(name: str, value: Any, zero: str) -> None:
    """``value`` is a number >= 0; ``zero`` says what 0 means (in the ConfigError)."""
    if not (isinstance(value, int | float) and value >= 0):
        raise ConfigError(f"{name} must be >= 0 (0: {zero}), got {value!r}")


@dataclass(frozen=True, kw_only=True)
class _Source:
    """What every ``[[sources]]`` table names: its ``kind`` and the ``robot`` it feeds (may be
    left out when the config has one robot)."""

    kind: str = ""
    robot: str = ""

    def __post_init__(self) -> None:
        if not isinstance(self.robot, str) or "/" in self.robot or "*" in self.robot:
            raise ConfigError(f"robot must be a robot name, got {self.robot!r}")


@dataclass(frozen=True, kw_only=True)
class _Replay(_Source):
    """A source that replays its time at ``speed`` x real time (0: as fast as possible), once
    its streams have subscribers or ``wait_subscribers_s`` (s) have passed (0: at once)."""

    speed: float = 1.0
    wait_subscribers_s: float = 10.0

    def __post_init__(self) -> None:
        super().__post_init__()
        _non_negative("speed", self.speed, "as fast as possible")
        _non_negative("wait_subscribers_s", self.wait_subscribers_s, "at once")


@dataclass(frozen=True, kw_only=True)
class SimSourceConfig(_Replay):
    """The simulated cell: an ``n``-point campaign of ``scenario`` at ``speed`` x real time
    (0: as fast as possible), one visit every ``period_s`` (s)."""

    kind: str = "sim"
    scenario: str = "paper"
    n: int = 1000
    seed: int = 0
    period_s: float = 0.6
    settle_s: float = 0.3

    def __post_init__(self) -> None:
        super().__post_init__()
        if not (isinstance(self.n, int) and self.n >= 1):
            raise ConfigError(f"n must be an int >= 1, got {self.n!r}")
        _positive(period_s=self.period_s, settle_s=self.settle_s)


@dataclass(frozen=True, kw_only=True)
class DatasetSourceConfig(_Replay):
    """A robocal dataset file streamed as timed samples at ``speed`` x its recorded time (0: as
    fast as possible); ``period_s`` > 0 re-times the rows to one visit per period (s), for
    datasets without usable time; rates (Hz) and the settle/dwell/lead times (s) of the stream."""

    kind: str = "dataset"
    path: str = ""
    period_s: float = 0.0
    joint_rate_hz: float = 125.0
    temperature_rate_hz: float = 1.0
    settle_s: float = 0.5
    dwell_s: float = 0.1
    lead_s: float = 1.0

    def __post_init__(self) -> None:
        super().__post_init__()
        if not isinstance(self.path, str) or not self.path:
            raise ConfigError("path must name a dataset file (kind = 'dataset')")
        _non_negative("period_s", self.period_s, "recorded time")
        _positive(
            joint_rate_hz=self.joint_rate_hz,
            temperature_rate_hz=self.temperature_rate_hz,
            settle_s=self.settle_s,
            dwell_s=self.dwell_s,
            lead_s=self.lead_s,
        )


@dataclass(frozen=True, kw_only=True)
class Ros2SourceConfig(_Source):
    """ROS 2 over Zenoh (rmw_zenoh): ``sensor_msgs/msg/JointState`` on ``joint_topic`` (its
    ``joint_names`` in the description's joint order) and the tracker's ``pose_type`` on
    ``pose_topic`` in robocal ``frame``; the ROS graph's Zenoh router at ``connect``."""

    kind: str = "ros2"
    connect: tuple[str, ...] = ("tcp/127.0.0.1:7447",)
    domain_id: int = 0
    joint_topic: str = "/joint_states"
    joint_names: tuple[str, ...] = ()
    pose_topic: str = "/tracker/pose"
    pose_type: str = "PoseStamped"
    frame: str = "tracker"
    frame_id: str = ""
    reconnect_s: float = 1.0
    max_queue: int = 100_000

    def __post_init__(self) -> None:
        super().__post_init__()
        if not self.connect or not all(isinstance(e, str) and "/" in e for e in self.connect):
            raise ConfigError(
                f"connect must list endpoints like tcp/127.0.0.1:7447, got {self.connect!r}"
            )
        if not (isinstance(self.domain_id, int) and 0 <= self.domain_id <= 232):
            raise ConfigError(f"domain_id must be an int in 0..232, got {self.domain_id!r}")
        for name in ("joint_topic", "pose_topic"):
            topic = getattr(self, name)
            if not isinstance(topic, str) or not topic.strip("/") or "*" in topic:
                raise ConfigError(f"{name} must be a ROS topic name, got {topic!r}")
        names = self.joint_names
        if not names or not all(isinstance(n, str) and n for n in names):
            raise ConfigError("joint_names must list the ROS joint names in joint order")
        if len(set(names)) != len(names):
            raise ConfigError(f"joint_names repeat: {list(names)}")
        if self.pose_type not in POSE_TYPES:
            raise ConfigError(f"pose_type must be one of {POSE_TYPES}, got {self.pose_type!r}")
        if self.frame not in FRAMES:
            raise ConfigError(f"frame must be one of {FRAMES}, got {self.frame!r}")
        _positive(reconnect_s=self.reconnect_s, max_queue=self.max_queue)


@dataclass(frozen=True, kw_only=True)
class OpcUaSourceConfig(_Source):
    """OPC UA temperatures: the server at ``url`` read every ``period_s`` (s), one node id per
    temperature channel (``nodes = {ambient = "ns=2;s=Cell.Ambient", ...}``, °C)."""

    kind: str = "opcua"
    url: str = ""
    nodes: tuple[tuple[str, str], ...] = ()
    period_s: float = 1.0
    timeout_s: float = 2.0
    reconnect_s: float = 1.0

    def __post_init__(self) -> None:
        super().__post_init__()
        if not (isinstance(self.url, str) and self.url.startswith("opc.tcp://")):
            raise ConfigError(f"url must look like opc.tcp://host:4840, got {self.url!r}")
        nodes = self.nodes
        if isinstance(nodes, dict):
            nodes = tuple(nodes.items())
            object.__setattr__(self, "nodes", nodes)
        if not nodes or not all(
            isinstance(c, str) and c and isinstance(n, str) and n for c, n in nodes
        ):
            raise ConfigError("nodes must map temperature channels to OPC UA node ids")
        _positive(period_s=self.period_s, timeout_s=self.timeout_s)
        _positive(reconnect_s=self.reconnect_s)


SourceConfig = SimSourceConfig | DatasetSourceConfig | Ros2SourceConfig | OpcUaSourceConfig
KINDS: dict[str, type] = {
    "sim": SimSourceConfig,
    "dataset": DatasetSourceConfig,
    "ros2": Ros2SourceConfig,
    "opcua": OpcUaSourceConfig,
}


def source_class(raw: Any) -> type:
    """The config class of a ``[[sources]]`` table by its ``kind``."""
    kind = raw.get("kind") if isinstance(raw, dict) else None
    if kind not in KINDS:
        raise ConfigError(f"[[sources]] kind must be one of {sorted(KINDS)}, got {kind!r}")
    return KINDS[kind]


def with_speed(sources: tuple[SourceConfig, ...], speed: float) -> tuple[SourceConfig, ...]:
    """The sources with ``speed`` (x recorded time, 0: as fast as possible) for those that replay
    (dataset, sim); ConfigError (one line) for a negative speed.

    >>> with_speed((DatasetSourceConfig(path="a.parquet"),), 10.0)[0].speed
    10.0
    """
    return tuple(replace(s, speed=speed) if isinstance(s, _Replay) else s for s in sources)
