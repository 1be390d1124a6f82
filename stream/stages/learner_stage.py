"""The learner stage: batches in; model snapshots, metrics and the latest-model queryable out.

Snapshots are published on ``.../model`` as the framed payload of stream.messages (header JSON
+ safetensors); the same payload answers queries on ``.../model`` so a late joiner gets the
newest model at once. With a checkpoint path, the state is written after every update and
restored on start (a restart loses no accepted batch).

Batches are numbered by the window per run (``epoch``, ``seq``, ``first``); the stage keeps,
with the checkpoint, the last ``seq`` and next point index of the :data:`KEPT_EPOCHS` window
runs it heard from last, and renumbers the batches it learns with its own counter. So a
restarted window (same epoch, numbering continued; or a new epoch) is never refused as a
duplicate, a batch already learned is, and a gap in the numbering is reported as points lost.
A batch whose ``seq`` jumps more than ``max_seq_jump`` ahead, or whose epoch lies ahead of the
clock, is refused as ``future``. A checkpoint that cannot be written (full disk, read-only
directory) leaves no temporary file and the previous checkpoint intact, and ends the stage.
"""

from __future__ import annotations

import threading
import time
from collections import deque
from dataclasses import replace
from pathlib import Path

import numpy as np
import zenoh

from kinematics.description import RobotDescription
from learner.snapshot import snapshot_to_bytes
from stream.bus import Received
from stream.learner_core import LearnerCore, LearnerStageConfig, Update
from stream.log import JsonLogger
from stream.messages import (
    Batch,
    Metrics,
    ModelHeader,
    RejectedMessageError,
    decode,
    encode,
    encode_model,
)
from stream.stages._base import Stage
from stream.state import remove_temporaries

#: Window runs whose numbering the learner remembers (the most recently used ones).
KEPT_EPOCHS = 4


class LearnerStage(Stage):
    """Runs :class:`~stream.learner_core.LearnerCore` on the ``batches`` of one robot."""

    name = "learner"

    def __init__(
        self,
        session: zenoh.Session,
        cell: str,
        robot: str,
        desc: RobotDescription,
        cfg: LearnerStageConfig,
        T_W_0: np.ndarray | None = None,
        checkpoint: str | Path | None = None,
        logger: JsonLogger | None = None,
        max_seq_jump: int = 1000,
        max_clock_ahead_s: float = 300.0,
    ) -> None:
        super().__init__(session, cell, robot, logger)
        self.core = LearnerCore(desc, cfg, T_W_0)
        self.max_seq_jump, self.max_clock_ahead_s = max_seq_jump, max_clock_ahead_s
        self.duplicates = 0
        self.lost_points = 0
        self.checkpoint_path = None if checkpoint is None else Path(checkpoint)
        self.latest: bytes | None = None
        self.last_update: Update | None = None
        self.metrics: deque[Metrics] = deque(maxlen=10_000)
        self._lock = threading.Lock()
        if self.checkpoint_path is not None and self.checkpoint_path.exists():
            self.core.restore(self.checkpoint_path)
            self.log.info(
                "checkpoint_restored",
                robot=robot,
                version=self.core.learner.version,
                windows={
                    e: {"last_seq": s, "next_point": f} for e, (s, f) in self.core.windows.items()
                },
            )
            self._publish(self._restored_update())
        self.answer("model", self._reply_latest)
        self.subscribe("batches")

    def _restored_update(self) -> Update:
        learner = self.core.learner
        header = ModelHeader(
            model_version=learner.version, robot=self.robot, n_seen=learner.n_seen, t=0.0
        )
        snap = snapshot_to_bytes(learner.model, {"model_version": learner.version})
        return Update(header, snap, self.core.metrics(float("nan"), 0.0, None))

    def handle(self, item: Received) -> None:
        batch = decode(item.payload, Batch)
        lost = self._check_order(batch)
        core = self.core
        update = core.add_batch(replace(batch, seq=core.last_seq + 1))
        core.windows.pop(batch.epoch, None)  # most recently used last
        core.windows[batch.epoch] = (batch.seq, batch.first + len(batch.points))
        for old in list(core.windows)[:-KEPT_EPOCHS]:
            del core.windows[old]
        self.counter.accept()
        if lost:
            self.lost_points += lost
            self.counter.drop("lost", lost)
            self.log.info(
                "points_lost",
                robot=self.robot,
                epoch=batch.epoch,
                seq=batch.seq,
                lost=lost,
                lost_total=self.lost_points,
            )
        if update is not None:
            self._publish(update)
            self._checkpoint()

    def _check_order(self, b: Batch) -> int:
        """Refuse a batch already learned (``duplicate``) or implausibly far ahead
        (``future``); the number of points lost before it."""
        if b.epoch > (time.time() + self.max_clock_ahead_s) * 1000:
            raise RejectedMessageError("future", f"batch epoch {b.epoch} ms is ahead of the clock")
        last_seq, next_first = self.core.windows.get(b.epoch, (-1, 0))
        if b.seq <= last_seq:
            self.duplicates += 1
            raise RejectedMessageError("duplicate", f"batch {b.epoch}/{b.seq} already learned")
        if b.seq > last_seq + self.max_seq_jump or b.first > next_first + self.max_seq_jump**2:
            raise RejectedMessageError(
                "future", f"batch seq {b.seq} jumps more than {self.max_seq_jump} past {last_seq}"
            )
        return max(b.first - next_first, 0)

    def _checkpoint(self) -> None:
        """Write the checkpoint; on OSError remove the temporary file and re-raise (fatal)."""
        if self.checkpoint_path is None:
            return
        try:
            self.core.checkpoint(self.checkpoint_path)
        except OSError:
            remove_temporaries(self.checkpoint_path)
            raise

    def _publish(self, update: Update) -> None:
        payload = encode_model(update.header, update.snapshot)
        with self._lock:
            self.latest = payload
        self.last_update = update
        self.metrics.append(update.metrics)
        self.put("model", payload)
        self.put("metrics", encode(update.metrics))
        self.log.info(
            "model_published",
            robot=self.robot,
            version=update.header.model_version,
            n_seen=update.header.n_seen,
            test_mean_mm=round(update.metrics.test_mean_mm, 4),
        )

    def _reply_latest(self, query: zenoh.Query) -> None:
        with self._lock:
            latest = self.latest
        if latest is not None:
            query.reply(self.key("model"), latest)

    def finish(self) -> None:
        self._checkpoint()
