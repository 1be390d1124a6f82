"""The window stage: source samples of one robot in, data points and batches out."""

from __future__ import annotations

import zenoh

from stream.bus import Received
from stream.log import JsonLogger
from stream.messages import STREAM_TYPES, decode, encode, split_key
from stream.stages._base import Stage
from stream.window import Batcher, Joiner, WindowConfig


class WindowStage(Stage):
    """Joins ``joints``/``tracker``/``temperature`` into ``points`` and ``batches``."""

    name = "window"

    def __init__(
        self,
        session: zenoh.Session,
        cell: str,
        robot: str,
        cfg: WindowConfig,
        logger: JsonLogger | None = None,
    ) -> None:
        super().__init__(session, cell, robot, logger)
        self.joiner = Joiner(cfg, self.counter)
        self.batcher = Batcher(cfg.batch_size)
        self.points = 0
        self.batches = 0
        for stream in ("joints", "tracker", "temperature"):
            self.subscribe(stream)

    @property
    def received(self) -> int:
        """Samples handled so far, accepted or dropped."""
        return self.counter.accepted + sum(self.counter.dropped.values())

    def handle(self, item: Received) -> None:
        stream = split_key(item.key)[2]
        self._emit(self.joiner.push(decode(item.payload, STREAM_TYPES[stream])))

    def _emit(self, points: list) -> None:
        for p in points:
            self.put("points", encode(p))
            self.points += 1
        for b in self.batcher.add(points):
            self.put("batches", encode(b))
            self.batches += 1

    def end_of_stream(self) -> None:
        """Resolve pending tracker samples and send the partial batch (call after drain)."""
        self.worker.call(self._flush)  # the worker thread owns the joiner

    def _flush(self) -> None:
        self._emit(self.joiner.flush())
        for b in self.batcher.flush():
            self.put("batches", encode(b))
            self.batches += 1
