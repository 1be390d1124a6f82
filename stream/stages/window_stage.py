"""The window stage: source samples of one robot in, data points and batches out.

With a state path the window keeps its run epoch, next batch ``seq`` and point count in a small
JSON file, written atomically before the points it counts are sent (one write per joined point;
joint samples write nothing), so that after a restart, even a ``kill -9``, its batches continue
the numbering the learner knows: none is refused as a duplicate, and the learner counts exactly
the points it never learned. The file also holds the points of the batch being filled, so a
restart sends them in the next batch: no joined point is lost to a ``kill -9``.
"""

from __future__ import annotations

import json
import time
from pathlib import Path

import zenoh

from kinematics.errors import ConfigError, RobocalError
from stream.log import JsonLogger
from stream.stages._base import Stage
from stream.state import write_atomic
from stream.window import Batcher, Joiner, WindowConfig
from stream.worker import Received
from wire import (
    STREAM_TYPES,
    Batch,
    DataPoint,
    check_count,
    decode,
    encode,
    from_dict,
    split_key,
    to_dict,
)

STATE_SCHEMA = "robocal.window_state"
#: A forward jump in a source's ``seq`` up to this many is counted as samples ``missed``
#: (lost on the way: a router restart, a dropped link); a larger one is a renumbered source.
MAX_COUNTED_GAP = 1_000_000


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
        state_path: str | Path | None = None,
    ) -> None:
        self.state_path = None if state_path is None else Path(state_path)
        epoch, seq, count, pending = self._load_state()
        self.batcher = Batcher(cfg.batch_size, epoch, seq, count - len(pending))
        restored = self.batcher.add(list(pending))  # full batches if batch_size shrank
        super().__init__(session, cell, robot, logger)
        self.joiner = Joiner(cfg, self.counter)
        if self.state_path is not None:
            self._save_state()
            self.log.info(
                "window_state", robot=robot, epoch=epoch, next_seq=seq, points=count,
                pending=len(pending),
            )  # fmt: skip
        self.points = 0
        self.batches = 0
        #: ``(epoch, seq)`` of the last batch sent, None before the first.
        self.last_batch: tuple[int, int] | None = None
        self._last_seq: dict[str, tuple[int, float]] = {}
        self._emit([], restored)
        for stream in ("joints", "tracker", "temperature"):
            self.subscribe(stream)

    def _load_state(self) -> tuple[int, int, int, tuple[DataPoint, ...]]:
        """``(epoch, next batch seq, points, pending points)`` from the state file, or a new
        epoch (ms)."""
        new = (int(time.time() * 1000), 0, 0, ())
        if self.state_path is None or not self.state_path.exists():
            return new
        try:
            raw = json.loads(self.state_path.read_text())
            if raw.get("schema") != STATE_SCHEMA:
                raise ValueError(f"schema {raw.get('schema')!r}")
            values = tuple(raw[k] for k in ("epoch", "next_seq", "points"))
            for k, v in zip(("epoch", "next_seq", "points"), values, strict=True):
                check_count(k, v)
            pending = tuple(from_dict(p, DataPoint) for p in raw.get("pending", []))
            if len(pending) > values[2]:
                raise ValueError(f"{len(pending)} pending points of {values[2]}")
        except (ValueError, KeyError, AttributeError, TypeError, OSError, RobocalError) as exc:
            raise ConfigError(f"{self.state_path}: unreadable window state: {exc}") from None
        return (*values, pending)  # type: ignore[return-value]

    def _save_state(self) -> None:
        b = self.batcher
        state = {"schema": STATE_SCHEMA, "epoch": b.epoch, "next_seq": b.next_seq}
        state["points"] = b.count
        state["pending"] = [to_dict(p) for p in b.pending]
        write_atomic(self.state_path, json.dumps(state).encode())

    @property
    def received(self) -> int:
        """Samples handled so far, accepted or dropped (not those ``missed`` upstream)."""
        dropped = self.counter.dropped
        return self.counter.accepted + sum(dropped.values()) - dropped["missed"]

    def handle(self, item: Received) -> None:
        stream = split_key(item.key)[2]
        sample = decode(item.payload, STREAM_TYPES[stream])
        self._count_missed(stream, sample.seq, sample.t)
        self._emit(self.joiner.push(sample, now=item.received_t))

    def _count_missed(self, stream: str, seq: int, t: float) -> None:
        """Count the samples a gap in a source's numbering says never arrived (``missed``).
        Only a sample later in time moves the count on (a forged or stale number with an earlier
        time counts nothing); a lower number later in time is a restarted source."""
        last = self._last_seq.get(stream)
        if last is not None and t <= last[1]:
            return
        self._last_seq[stream] = (seq, t)
        if last is not None and 1 < seq - last[0] <= MAX_COUNTED_GAP:
            self.counter.drop("missed", seq - last[0] - 1)
            self.log.limited(
                "samples_missed", key=f"missed:{stream}", robot=self.robot, stream=stream,
                missed=seq - last[0] - 1, missed_total=self.counter.dropped["missed"],
            )  # fmt: skip

    def _emit(self, points: list, batches: list[Batch] | None = None) -> None:
        """Count and number ``points`` (and batch them) in the state file, then send them: a
        number, once sent, is never sent again."""
        batches = self.batcher.add(points) + (batches or [])
        if not (points or batches):
            return
        if self.state_path is not None:
            self.persist(self._save_state, "window state", self.state_path)
        for p in points:
            self.put("points", encode(p))
            self.points += 1
        for b in batches:
            self.put("batches", encode(b))
            self.batches += 1
            self.last_batch = (b.epoch, b.seq)

    def end_of_stream(self, timeout_s: float = 60.0) -> None:
        """Resolve pending tracker samples and send the partial batch (call after drain)."""
        self.worker.call(self._flush, timeout_s)  # the worker thread owns the joiner

    def _flush(self) -> None:
        self._emit(self.joiner.flush())
        self._emit([], self.batcher.flush())

    def finish(self) -> None:
        if self.state_path is not None:
            self._save_state()
