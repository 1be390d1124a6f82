"""The recorder stage: everything under ``robocal/<cell>/**`` into MCAP (a new file per start,
never an old one overwritten, split into parts by size or time; see
:class:`~stream.mcap_io.McapRecorder`). Each part carries one ``robocal.robot`` metadata record
per robot: its key name, description name and hash, joints, and the frames known at start."""

from __future__ import annotations

import json
import time
from collections.abc import Sequence
from pathlib import Path
from typing import Protocol

import numpy as np
import zenoh

from kinematics.description import load_description
from stream.log import JsonLogger
from stream.mcap_io import McapRecorder
from stream.stages._base import WAITABLE_ERRNOS, Stage
from stream.state import describe_os_error
from stream.trust import description_hash
from stream.worker import Received

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
        self._waiting = False  # the disk was full or read-only: a new part is due
        self._last_try = 0.0  # when a new part was last tried (s)
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
        if not self._waiting:
            try:
                self.recorder.add(item.key, item.payload, int(item.received_t * 1e9))
                self.counter.accept()
                return
            except OSError as exc:
                self._unwritable(exc)
        self.counter.drop("unwritable")

    def on_idle(self, now: float) -> None:
        if not self._waiting:
            try:
                self.recorder.maybe_flush()
            except OSError as exc:
                self._unwritable(exc)
        elif now - self._last_try >= self.retry_s:
            self._last_try = now
            try:
                self.recorder.reopen()
            except OSError:
                return
            self.log.info(
                "recording_resumed",
                stage=self.name,
                path=str(self.recorder.path),
                dropped=self.counter.dropped.get("unwritable", 0),
            )
            self._waiting = False

    def _unwritable(self, exc: OSError) -> None:
        """A full or read-only disk: fatal (``on_disk_full = "stop"``), or close the part as it
        is and count what arrives as ``unwritable`` until a new part can be started."""
        if self.on_disk_full != "wait" or exc.errno not in WAITABLE_ERRNOS:
            raise exc
        lost = self.recorder.abandon()
        self.counter.drop("unwritable", lost)  # accepted, then lost with the unflushed chunk
        self._waiting, self._last_try = True, time.time()
        self.log.log(
            "error",
            "recording_unwritable",
            stage=self.name,
            path=str(self.recorder.path),
            cause=describe_os_error(exc),
            lost_unflushed=lost,
            action="waiting, a new part once writable",
        )

    def finish(self) -> None:
        self.recorder.close()
