"""Sources from the daemon config: build one per ``[[sources]]`` table and run it in a thread.

The ROS 2 and OPC UA modules (``rosbags``, ``asyncua``) are imported only when a config names
them. A :class:`SourceThread` looks like a stage to the daemon's supervisor (``name``,
``robot``, ``failure``): a source that dies of an unexpected error stops the daemon with one
line, while a device that drops is the source's own business (it reconnects and counts).
"""

from __future__ import annotations

import threading

import zenoh

from kinematics.description import RobotDescription
from stream.log import JsonLogger
from stream.sources._base import Source
from stream.sources.config import (
    DatasetSourceConfig,
    OpcUaSourceConfig,
    Ros2SourceConfig,
    SimSourceConfig,
    SourceConfig,
)


def build_source(
    sc: SourceConfig, session: zenoh.Session, cell: str, robot: str, desc: RobotDescription
) -> Source:
    """The source of one ``[[sources]]`` table for ``robot`` (ConfigError: one line)."""
    if isinstance(sc, Ros2SourceConfig):
        from stream.sources.ros2 import Ros2Source

        return Ros2Source(session, cell, robot, sc, desc.n_joints)
    if isinstance(sc, OpcUaSourceConfig):
        from stream.sources.opcua import OpcUaSource

        declared = tuple(c for c, _ in desc.temperature_links)
        return OpcUaSource(session, cell, robot, sc, declared)
    if isinstance(sc, DatasetSourceConfig):
        from stream.sources.dataset import dataset_source

        return dataset_source(session, cell, robot, sc, desc)
    if isinstance(sc, SimSourceConfig):
        return sim_source(sc, session, cell, robot, desc)
    raise TypeError(f"not a source config: {sc!r}")


def sim_source(
    sc: SimSourceConfig, session: zenoh.Session, cell: str, robot: str, desc: RobotDescription
) -> Source:
    """The simulated cell of ``sc.scenario`` (its robot must be the description's)."""
    from kinematics.errors import ConfigError
    from sim_sources.cell import simulate
    from sim_sources.scenarios import get_scenario
    from sim_sources.streaming import StreamingConfig
    from stream.sources.sim import SimCellSource

    ds = simulate(get_scenario(sc.scenario), sc.n, sc.seed)
    if ds.meta.robot != desc.name:
        raise ConfigError(
            f"sources: scenario {sc.scenario!r} simulates {ds.meta.robot!r}, robot {robot!r} is "
            f"{desc.name!r}"
        )
    streaming = StreamingConfig(period_s=sc.period_s, settle_s=sc.settle_s)
    return SimCellSource(
        session, cell, robot, ds, streaming, sc.speed or None, sc.wait_subscribers_s
    )


class SourceThread:
    """Runs one source in a daemon thread; ``close()`` stops it within a bound."""

    name = "source"

    def __init__(self, source: Source, logger: JsonLogger) -> None:
        self.source, self.log = source, logger
        self.robot = source.robot
        self.name = f"source_{source.kind}"
        self.failure: BaseException | None = None
        self._thread = threading.Thread(target=self._run, name=self.name, daemon=True)

    def start(self) -> SourceThread:
        self._thread.start()
        return self

    def _run(self) -> None:
        try:
            self.source.start()
        except BaseException as exc:  # kept for the supervisor, which reports and stops
            self.failure = exc
        else:
            self.log.info(
                "source_finished", source=self.name, robot=self.robot, **self.source.diagnostics()
            )

    def close(self, timeout_s: float = 5.0) -> BaseException | None:
        """Stop the source and wait up to ``timeout_s`` (s); its fatal error, if any."""
        self.source.stop()
        if self._thread.ident is None:  # never started (the daemon failed to start)
            return None
        self._thread.join(timeout_s)
        self.log.info(
            "source_stopped",
            source=self.name,
            robot=self.robot,
            stopped=not self._thread.is_alive(),
            **self.source.diagnostics(),
        )
        return self.failure
