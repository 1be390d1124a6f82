"""The daemon configuration: frozen dataclasses loaded once from TOML (see deploy/).

>>> cfg = config_from_dict({"cell": "c1", "robot": [{"name": "r1", "description": "ur10"}]})
>>> cfg.robots[0].stages
('window', 'learner', 'compensation')
"""

from __future__ import annotations

from dataclasses import dataclass, field, fields
from pathlib import Path
from typing import Any

import numpy as np

from kinematics.errors import ConfigError, RobocalError
from kinematics.toml_io import load_toml
from learner.config import ContinualConfig, ModelConfig, TrainConfig
from stream.bus import BusConfig
from stream.compensation import CompensationConfig
from stream.learner_core import LearnerStageConfig
from stream.sources.config import SourceConfig, source_class
from stream.stages import ROBOT_STAGES
from stream.trust import ModelTrustConfig
from stream.window import WindowConfig

STAGES = ROBOT_STAGES  # the stage registry's per-robot names


@dataclass(frozen=True, kw_only=True)
class RobotConfig:
    """One robot: its key name, description (shipped name or TOML path), stages, ``T_W_0``."""

    name: str
    description: str
    stages: tuple[str, ...] = ("window", "learner", "compensation")
    T_W_0: tuple[tuple[float, ...], ...] | None = None

    def __post_init__(self) -> None:
        if not self.name or "/" in self.name or "*" in self.name:
            raise ConfigError(f"robot.name must be a plain key chunk, got {self.name!r}")
        bad = [s for s in self.stages if s not in STAGES]
        if bad:
            raise ConfigError(f"robot {self.name!r}: unknown stage(s) {bad}; known: {STAGES}")
        if self.T_W_0 is not None and np.asarray(self.T_W_0, dtype=float).shape != (4, 4):
            raise ConfigError(f"robot {self.name!r}: T_W_0 must be a 4x4 matrix")


@dataclass(frozen=True, kw_only=True)
class DashboardConfig:
    """Where the dashboard goes: an .rrd file, a served web viewer, or a running viewer;
    ``host`` is the name browsers reach this machine by (it goes into the viewer's URL)."""

    rrd: str | None = None
    serve: bool = False
    web_port: int = 9090
    grpc_port: int = 9876
    host: str = "localhost"
    connect: str | None = None

    def __post_init__(self) -> None:
        if not (self.rrd or self.serve or self.connect):
            raise ConfigError("dashboard needs rrd, serve = true or connect")


@dataclass(frozen=True, kw_only=True)
class RecorderConfig:
    """The MCAP file of the recorder, how often it flushes chunks (s), and when it starts a
    new part: past ``split_size_mb`` (MiB) or ``split_interval_s`` (s); None: never."""

    path: str
    flush_interval_s: float = 1.0
    split_size_mb: float | None = 1024.0
    split_interval_s: float | None = None

    def __post_init__(self) -> None:
        if not self.flush_interval_s > 0:
            raise ConfigError(f"recorder.flush_interval_s must be > 0, got {self.flush_interval_s}")
        for name in ("split_size_mb", "split_interval_s"):
            value = getattr(self, name)
            if value is not None and not (isinstance(value, int | float) and value > 0):
                raise ConfigError(f"recorder.{name} must be > 0 (or left out), got {value!r}")


@dataclass(frozen=True, kw_only=True)
class DaemonConfig:
    """Everything ``robocal run`` needs, validated at load."""

    cell: str = "cell1"
    bus: BusConfig = field(default_factory=BusConfig)
    robots: tuple[RobotConfig, ...] = ()
    #: ``[[sources]]``: devices (or a dataset, or the simulator) this daemon reads itself.
    sources: tuple[SourceConfig, ...] = ()
    window: WindowConfig = field(default_factory=WindowConfig)
    learner: LearnerStageConfig = field(default_factory=LearnerStageConfig)
    compensation: CompensationConfig = field(default_factory=CompensationConfig)
    dashboard: DashboardConfig | None = None
    recorder: RecorderConfig | None = None
    models: ModelTrustConfig = field(default_factory=ModelTrustConfig)
    checkpoint_dir: str | None = None
    log_per_s: float = 1.0
    torch_threads: int = 1
    #: SIGTERM/SIGINT to exit (s): queued work is abandoned past it; a watchdog ends the
    #: process 1.5 s later whatever is stuck.
    shutdown_timeout_s: float = 7.0
    #: A full disk or read-only state directory while running: ``"stop"`` (one line, exit 2)
    #: or ``"wait"`` (one line, state writes retried every second until they succeed).
    on_disk_full: str = "stop"

    def __post_init__(self) -> None:
        if self.on_disk_full not in ("stop", "wait"):
            raise ConfigError(f"on_disk_full must be 'stop' or 'wait', got {self.on_disk_full!r}")
        if not 0.5 <= self.shutdown_timeout_s <= 600:
            raise ConfigError(
                f"shutdown_timeout_s must be in 0.5..600, got {self.shutdown_timeout_s}"
            )
        if not self.cell or "/" in self.cell or "*" in self.cell:
            raise ConfigError(f"cell must be a plain key chunk, got {self.cell!r}")
        if not (isinstance(self.torch_threads, int) and self.torch_threads >= 1):
            raise ConfigError(f"torch_threads must be an int >= 1, got {self.torch_threads!r}")
        if not self.robots:
            raise ConfigError("config needs at least one [[robot]]")
        names = [r.name for r in self.robots]
        if len(set(names)) != len(names):
            raise ConfigError(f"robot names must be unique, got {names}")
        for sc in self.sources:
            if sc.robot not in names and not (sc.robot == "" and len(names) == 1):
                raise ConfigError(
                    f"[[sources]] kind {sc.kind!r}: robot {sc.robot!r} is not one of {names}"
                    " (robot may be left out when there is one)"
                )
        if any("dashboard" in r.stages for r in self.robots) and self.dashboard is None:
            raise ConfigError("a robot runs the dashboard stage but there is no [dashboard]")
        n = sum("dashboard" in r.stages for r in self.robots)
        if self.dashboard is not None and self.dashboard.serve and n > 1:
            d = self.dashboard  # robot i serves on web_port + i and grpc_port + i
            if abs(d.web_port - d.grpc_port) < n or max(d.web_port, d.grpc_port) + n > 65536:
                raise ConfigError(
                    f"dashboard: {n} robots serve on web_port..+{n - 1} and grpc_port..+{n - 1}; "
                    f"those ranges overlap or pass 65535 ({d.web_port}, {d.grpc_port})"
                )


def dashboard_index(cfg: DaemonConfig, robot: str) -> int:
    """The robot's place among the robots with a dashboard: its served ports' offset."""
    return [r.name for r in cfg.robots if "dashboard" in r.stages].index(robot)


def _build(cls: type, raw: Any, where: str) -> Any:
    if not isinstance(raw, dict):
        raise ConfigError(f"[{where}] must be a table, got {type(raw).__name__}")
    known = {f.name for f in fields(cls)}
    unknown = sorted(set(raw) - known)
    if unknown:
        raise ConfigError(f"[{where}] unknown field(s) {unknown}; known: {sorted(known)}")
    values = {k: tuple(map(_tuple, v)) if isinstance(v, list) else v for k, v in raw.items()}
    try:
        return cls(**values)
    except RobocalError as exc:
        raise ConfigError(f"[{where}] {exc}") from None
    except TypeError as exc:
        raise ConfigError(f"[{where}] {exc}") from None


def _tuple(v: Any) -> Any:
    return tuple(map(_tuple, v)) if isinstance(v, list) else v


def config_from_dict(raw: dict) -> DaemonConfig:
    """Build and validate a :class:`DaemonConfig` from the parsed TOML layout."""
    raw = dict(raw)
    learner_raw = dict(raw.pop("learner", {}))
    learner = _build(
        LearnerStageConfig,
        {
            **learner_raw,
            "model": _build(ModelConfig, learner_raw.pop("model", {}), "learner.model"),
            "train": _build(TrainConfig, learner_raw.pop("train", {}), "learner.train"),
            "continual": _build(
                ContinualConfig, learner_raw.pop("continual", {}), "learner.continual"
            ),
        },
        "learner",
    )
    robots = tuple(_build(RobotConfig, r, "robot") for r in raw.pop("robot", []))
    sources = tuple(_build(source_class(s), s, "sources") for s in raw.pop("sources", []))
    sections = {
        "bus": BusConfig,
        "window": WindowConfig,
        "compensation": CompensationConfig,
        "dashboard": DashboardConfig,
        "recorder": RecorderConfig,
        "models": ModelTrustConfig,
    }
    built = {k: _build(cls, raw.pop(k), k) for k, cls in sections.items() if k in raw}
    return _build(
        DaemonConfig,
        {**raw, **built, "learner": learner, "robots": robots, "sources": sources},
        "top level",
    )


def load_config(path: str | Path) -> DaemonConfig:
    """Read a daemon TOML config; any problem raises ConfigError naming the file."""
    return load_toml(path, "config file", config_from_dict)
