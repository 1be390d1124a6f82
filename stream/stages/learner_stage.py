"""The learner stage: batches in; model snapshots, metrics and the latest-model queryable out.

Snapshots are published on ``.../model`` as the framed payload of stream.messages (header JSON
+ safetensors); the same payload answers queries on ``.../model`` so a late joiner gets the
newest model at once. With a checkpoint path, the state is written after every update and
restored on start (a restart loses no accepted batch).
"""

from __future__ import annotations

import threading
from collections import deque
from pathlib import Path

import numpy as np
import zenoh

from kinematics.description import RobotDescription
from learner.snapshot import snapshot_to_bytes
from stream.bus import Received
from stream.learner_core import LearnerCore, LearnerStageConfig, Update
from stream.log import JsonLogger
from stream.messages import Batch, Metrics, ModelHeader, decode, encode, encode_model
from stream.stages._base import Stage


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
    ) -> None:
        super().__init__(session, cell, robot, logger)
        self.core = LearnerCore(desc, cfg, T_W_0)
        self.checkpoint_path = None if checkpoint is None else Path(checkpoint)
        self.latest: bytes | None = None
        self.last_update: Update | None = None
        self.metrics: deque[Metrics] = deque(maxlen=10_000)
        self._lock = threading.Lock()
        if self.checkpoint_path is not None and self.checkpoint_path.exists():
            self.core.restore(self.checkpoint_path)
            self.log.info("checkpoint_restored", robot=robot, version=self.core.learner.version)
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
        update = self.core.add_batch(decode(item.payload, Batch))
        self.counter.accept()
        if update is not None:
            self._publish(update)
            if self.checkpoint_path is not None:
                self.core.checkpoint(self.checkpoint_path)

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
        if self.checkpoint_path is not None:
            self.core.checkpoint(self.checkpoint_path)
