"""The recorder stage: everything under ``robocal/<cell>/**`` into MCAP (a new file per start,
never an old one overwritten, split into parts by size or time; see
:class:`~stream.mcap_io.McapRecorder`). Each part carries one ``robocal.robot`` metadata record
per robot: its key name, description name and hash, joints, and the frames known at start."""

from __future__ import annotations

import json
from collections.abc import Sequence
from pathlib import Path
from typing import Protocol

import numpy as np
import zenoh

from kinematics.description import load_description
from stream.bus import Received
from stream.log import JsonLogger
from stream.mcap_io import McapRecorder
from stream.stages._base import Stage
from stream.trust import description_hash

#: The metadata record of one robot of the cell.
ROBOT_METADATA = "robocal.robot"


class RobotLike(Protocol):
    """What the recorder reads of a ``stream.config.RobotConfig`` (not imported: the config
    module imports the stage registry)."""

    name: str
    description: str
    stages: tuple[str, ...]
    T_W_0: tuple[tuple[float, ...], ...] | None


def robot_metadata(cell: str, robot: RobotLike) -> dict[str, str]:
    """What a recording says about one robot: names, description hash, joints and frames
    (``T_W_0`` as configured, empty when the learner identifies it; ``T_6_S`` the tool)."""
    desc = load_description(robot.description)
    T_W_0 = "" if robot.T_W_0 is None else json.dumps(np.asarray(robot.T_W_0).tolist())
    return {
        "cell": cell,
        "robot": robot.name,
        "description": desc.name,
        "description_source": robot.description,
        "description_hash": description_hash(desc),
        "n_joints": str(desc.n_joints),
        "coupling": desc.coupling,
        "stages": ",".join(robot.stages),
        "T_W_0": T_W_0,
        "T_6_S": json.dumps(np.asarray(desc.tool).tolist()),
    }


class RecorderStage(Stage):
    """Records every key of the cell (one channel per key); flushes chunks every second."""

    name = "recorder"

    def __init__(
        self,
        session: zenoh.Session,
        cell: str,
        path: str | Path,
        flush_interval_s: float = 1.0,
        logger: JsonLogger | None = None,
        *,
        split_size_mb: float | None = None,
        split_interval_s: float | None = None,
        robots: Sequence[RobotLike] = (),
    ) -> None:
        super().__init__(session, cell, "all", logger)
        self.recorder = McapRecorder(
            path,
            flush_interval_s,
            split_bytes=None if split_size_mb is None else int(split_size_mb * 2**20),
            split_interval_s=split_interval_s,
            metadata=[(ROBOT_METADATA, robot_metadata(cell, r)) for r in robots],
        )
        self._subs.append(session.declare_subscriber(f"robocal/{cell}/**", self.worker.callback))

    def handle(self, item: Received) -> None:
        if "/alive/" in item.key:
            return
        self.recorder.add(item.key, item.payload, int(item.received_t * 1e9))
        self.counter.accept()

    def on_idle(self, now: float) -> None:
        self.recorder.maybe_flush()

    def finish(self) -> None:
        self.recorder.close()
