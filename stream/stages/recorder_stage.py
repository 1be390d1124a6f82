"""The recorder stage: everything under ``robocal/<cell>/**`` into an MCAP file (a new file
per start, never an old one overwritten; see :class:`~stream.mcap_io.McapRecorder`)."""

from __future__ import annotations

from pathlib import Path

import zenoh

from stream.bus import Received
from stream.log import JsonLogger
from stream.mcap_io import McapRecorder
from stream.stages._base import Stage


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
    ) -> None:
        super().__init__(session, cell, "all", logger)
        self.recorder = McapRecorder(path, flush_interval_s)
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
