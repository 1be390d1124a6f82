"""The learner stage: batches in; model snapshots, metrics and the latest-model queryable out.

Snapshots are published on ``.../model`` as the framed payload of wire.codec (header JSON +
safetensors); the same payload answers queries on ``.../model`` so a late joiner gets the newest
model at once; a ``start_from`` model file is published at once as
:func:`~learner.carry.before_day` serves it. With a checkpoint path, the state is written after
every update and restored on start (published at once; after a pause of ``new_day_after_h`` by
the wall clock as ``before_day`` serves it), and every batch the stage accepts is first appended
(fsync'd) to an :class:`~stream.state.AcceptedLog` beside it that the next checkpoint clears; a
restart replays the log after the checkpoint, so even a ``kill -9`` loses no accepted point. The
replay is the worker's first job, queued before the stage subscribes: batches that arrive while it
trains (seconds; about a minute for a carried day's fresh network) wait behind it, not lost.

Batches are numbered by the window per run (``epoch``, ``seq``, ``first``); the stage keeps,
with the checkpoint, the last ``seq`` and next point index of the :data:`KEPT_EPOCHS` window
runs it heard from last, and renumbers the batches it learns with its own counter. So a
restarted window (same epoch, numbering continued; or a new epoch) is never refused as a
duplicate, a batch already learned is, and a gap in the numbering is reported as points lost.
A batch whose ``seq`` jumps more than ``max_seq_jump`` ahead, or whose epoch lies ahead of the
clock, is refused as ``future``. Forged numbers cannot wedge the stage: a duplicate is a
``seq`` learned in this run (or below what the checkpoint holds), not merely one below the
highest seen; the kept numbering moves by the next ``seq`` or by a jump that the batch after it
confirms, so a forged jump reaches neither the checkpoint nor the lost count; the run forgotten
first is the least advanced one, so a flood of forged epochs does not push the genuine run out
(and an epoch the stage does not know is joined where it stands). The checkpoint file is
written with robocal's one atomic writer (:func:`stream.state.write_atomic`): one that cannot be
written (full disk, read-only directory) leaves no temporary file and the previous checkpoint
intact, and ends the stage (or waits, ``on_disk_full = "wait"``).
"""

from __future__ import annotations

import threading
import time
from collections import deque
from dataclasses import replace
from pathlib import Path

import numpy as np
import zenoh

from kinematics.dataset import remove_stale_temporaries
from kinematics.description import RobotDescription
from kinematics.errors import SnapshotError
from learner.continual_records import UpdateMetrics
from learner.train_process import TrainProcess
from stream.learner_core import LearnerCore, LearnerStageConfig, Update
from stream.log import JsonLogger
from stream.stages._base import Stage
from stream.state import AcceptedLog, write_atomic
from stream.worker import Received
from wire import (
    Batch,
    Metrics,
    RejectedMessageError,
    decode,
    encode,
    encode_model,
)

#: Window runs whose numbering the learner remembers (the least advanced is forgotten first).
KEPT_EPOCHS = 16
#: Learned ``seq`` s remembered per window run; past it the oldest half is forgotten.
KEPT_SEQS = 100_000


def write_checkpoint(core: LearnerCore, path: str | Path) -> Path | None:
    """Write the core's checkpoint to ``path`` atomically (None, nothing written, before a
    model); an OSError names ``path`` and leaves no temporary file."""
    data = core.checkpoint()
    return None if data is None else write_atomic(path, data)


def read_checkpoint(core: LearnerCore, path: str | Path) -> None:
    """Continue ``core`` from a checkpoint file; SnapshotError naming the file otherwise."""
    try:
        core.restore(Path(path).read_bytes())
    except OSError as exc:
        raise SnapshotError(f"{path}: unreadable checkpoint: {exc}") from None
    except SnapshotError as exc:
        raise SnapshotError(f"{path}: {exc}") from None


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
        self.accepted_log = None
        if self.checkpoint_path is not None:
            self.accepted_log = AcceptedLog(self.checkpoint_path.with_suffix(".accepted"))
            if stale := remove_stale_temporaries(self.checkpoint_path):
                self.log.info("stale_temporaries_removed", robot=robot, files=stale)
        #: Per epoch: the lowest ``seq`` that may still be new, and the ``seq`` s learned above it.
        self._learned: dict[int, tuple[int, set[int]]] = {}
        #: Per epoch: a ``(seq, first)`` that jumped past the numbering, until the next confirms.
        self._jumps: dict[int, tuple[int, int]] = {}
        #: Per epoch: batches its numbering advanced by; the least advanced run is forgotten
        #: first, so a flood of forged one-batch epochs cannot push the genuine run out.
        self._weight: dict[int, int] = {}
        self.replayed_points = 0
        self.latest: bytes | None = None
        self.last_update: Update | None = None
        self.metrics: deque[Metrics] = deque(maxlen=10_000)
        self._lock = threading.Lock()
        restored = self.checkpoint_path is not None and self.checkpoint_path.exists()
        if restored:
            read_checkpoint(self.core, self.checkpoint_path)
            self.log.info(
                "checkpoint_restored",
                robot=robot,
                version=self.core.learner.version,
                windows={
                    e: {"last_seq": s, "next_point": f} for e, (s, f) in self.core.windows.items()
                },
            )
            self._weight = {e: s + 1 for e, (s, _) in self.core.windows.items()}
        if self.core.learner is not None:  # restored, or a model file: none of the day seen
            new_day = self.core.paused(time.time()) if restored else True
            metrics = self.core.metrics(float("nan"), 0.0, None)
            self._publish(self.core.published(0.0, metrics, new_day))
        self.trainer = TrainProcess(self._train_failed) if cfg.train_process else None
        self.core.trainer = self.trainer
        self.answer("model", self._reply_latest)
        self.worker.submit(self._replay)  # first on the worker: what arrives meanwhile waits
        self.subscribe("batches")

    def _replay(self) -> None:
        """Learn the batches of the accepted log that the checkpoint does not hold yet."""
        if self.accepted_log is None:
            return
        n_batches = 0
        for payload in self.accepted_log.records():
            try:
                batch = decode(payload, Batch)
                last_seq = self.core.windows.get(batch.epoch, (-1, 0))[0]
                if batch.epoch in self.core.windows and batch.seq <= last_seq:
                    continue  # the checkpoint was written, the log not yet cleared
                self._learn(batch, self._check_order(batch))
            except RejectedMessageError as exc:  # refused when it came, refused again
                self.counter.drop(exc.reason)
                continue
            n_batches += 1
            self.replayed_points += len(batch.points)
        if n_batches:
            self.log.info(
                "accepted_replayed",
                robot=self.robot,
                batches=n_batches,
                points=self.replayed_points,
            )

    def handle(self, item: Received) -> None:
        batch = decode(item.payload, Batch)
        lost = self._check_order(batch)
        if self.accepted_log is not None:  # durable before it is learned
            self.persist(lambda: self.accepted_log.append(item.payload), "accepted log")
        self._learn(batch, lost)

    def _learn(self, batch: Batch, lost: int) -> None:
        core = self.core
        update = core.add_batch(replace(batch, seq=core.last_seq + 1))
        self._report_poisoning(core.last_step)
        self._advance(batch)
        floor, learned = self._learned.setdefault(batch.epoch, (0, set()))  # joined: none below
        learned.add(batch.seq)
        if len(learned) > KEPT_SEQS:
            keep = sorted(learned)[-KEPT_SEQS // 2 :]
            self._learned[batch.epoch] = (keep[0], set(keep))
        while len(core.windows) > KEPT_EPOCHS:  # the least advanced run, the oldest of those
            order = list(core.windows)
            old = min(order, key=lambda e: (self._weight.get(e, 0), order.index(e)))
            del core.windows[old]
            self._learned.pop(old, None)
            self._jumps.pop(old, None)
            self._weight.pop(old, None)
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

    def _report_poisoning(self, step: UpdateMetrics | None) -> None:
        """Count the batch's quarantined points (diagnostics ``dropped["quarantined"]``) and a
        withheld update (``dropped["withheld"]``, ``refused["update"]``); log every withheld
        update once, quarantined points at a bounded rate."""
        if step is None:
            return
        total = self.core.learner.quarantine.quarantined
        if step.quarantined:
            self.counter.drop("quarantined", step.quarantined)
            self.log.limited(
                "points_quarantined",
                key="learner:quarantined",
                robot=self.robot,
                points=step.quarantined,
                total=total,
            )
        if step.withheld:
            tol = self.core.cfg.continual.quarantine.publish_tolerance
            detail = f"held-out error would grow more than {tol:.0%} over {step.holdout_mm:.4f} mm"
            self.counter.refuse("update", "withheld", detail)
            self.log.info(
                "update_withheld",
                robot=self.robot,
                version=self.core.learner.version,
                holdout_mm=round(step.holdout_mm, 4),
                withheld_total=self.core.learner.n_withheld,
            )

    def has_learned(self, epoch: int, seq: int) -> bool:
        """Whether batch ``seq`` of the window run ``epoch`` was learned (or lies below what
        this stage still tracks of that run)."""
        floor, learned = self._learned.get(epoch, (0, set()))
        return seq < floor or seq in learned

    def _advance(self, b: Batch) -> None:
        """Move the run's numbering (kept with the checkpoint) on: by the next ``seq``, or by a
        jump once the batch after it confirms it (a forged jump is never confirmed, so it never
        reaches the checkpoint and cannot make a restarted learner refuse genuine batches)."""
        windows = self.core.windows
        last_seq, next_point = windows.pop(b.epoch, (b.seq - 1, b.first))  # unknown: joined
        end = b.first + len(b.points)
        jump = self._jumps.get(b.epoch)
        if b.seq == last_seq + 1 or (jump is not None and b.seq == jump[0] + 1):
            last_seq, next_point = b.seq, max(next_point, end)
            self._weight[b.epoch] = self._weight.get(b.epoch, 0) + 1
            if jump is not None and b.seq == jump[0] + 1:
                del self._jumps[b.epoch]
        elif b.seq > last_seq + 1:
            self._jumps[b.epoch] = (b.seq, b.first)
        windows[b.epoch] = (last_seq, next_point)  # most recently used last

    def _check_order(self, b: Batch) -> int:
        """Refuse a batch already learned (``duplicate``) or implausibly far ahead
        (``future``); the number of points lost before it (a jump's: when it is confirmed)."""
        if b.epoch > (time.time() + self.max_clock_ahead_s) * 1000:
            raise RejectedMessageError("future", f"batch epoch {b.epoch} ms is ahead of the clock")
        if b.epoch not in self.core.windows:
            return 0  # a run this stage never knew, or forgot: joined where it stands
        last_seq, next_first = self.core.windows[b.epoch]
        floor, learned = self._learned.setdefault(b.epoch, (last_seq + 1, set()))
        if b.seq < floor or b.seq in learned:
            self.duplicates += 1
            raise RejectedMessageError("duplicate", f"batch {b.epoch}/{b.seq} already learned")
        if b.seq > last_seq + self.max_seq_jump or b.first > next_first + self.max_seq_jump**2:
            raise RejectedMessageError(
                "future", f"batch seq {b.seq} jumps more than {self.max_seq_jump} past {last_seq}"
            )
        jump = self._jumps.get(b.epoch)
        if jump is not None and b.seq == jump[0] + 1:
            return max(jump[1] - next_first, 0)  # the jump is confirmed: the gap before it
        return max(b.first - next_first, 0) if b.seq == last_seq + 1 else 0

    def _checkpoint(self) -> None:
        """Write the checkpoint, then clear the accepted log it now holds; on OSError re-raise
        (fatal) or wait (``on_disk_full``)."""
        if self.checkpoint_path is None:
            return
        self.persist(self._write_checkpoint, "checkpoint", self.checkpoint_path)

    def _write_checkpoint(self) -> None:
        written = write_checkpoint(self.core, self.checkpoint_path)
        if written is not None and self.accepted_log is not None:
            self.accepted_log.clear()

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

    def _train_failed(self, reason: str) -> None:
        self.log.log("warning", "train_process_failed", robot=self.robot, reason=reason[:300])

    def close(self, timeout_s: float = 60.0) -> BaseException | None:
        """Close as every stage does, then end the training process."""
        try:
            return super().close(timeout_s)
        finally:
            if self.trainer is not None:
                self.trainer.close()

    def finish(self) -> None:
        self._checkpoint()
