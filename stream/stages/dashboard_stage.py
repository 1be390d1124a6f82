"""The dashboard stage: metrics, points, models, diagnostics and compensation answers of one
robot into a Rerun recording.

A model is drawn only when :class:`~stream.trust.ModelGate` adopts it (as the compensation
service does). A point is logged only when it fits the robot and the points before it (joint
count, secondary encoders, thermometers, frame; ``invalid`` otherwise), so one odd point never
spoils the points logged with it. Points are drawn in batches at most every
:data:`POINTS_EVERY_S`: a drawing costs the daemon's interpreter tens of milliseconds whatever
its size, and drawn at every 0.2 s idle tick, a stream of 40 points a second took a fifth of
it (BENCHMARKS.md, "The stream's cost in the daemon"). Compensation answers are the replies
the compensation service also puts on ``.../compensate`` (a query's own reply reaches only its
asker).
"""

from __future__ import annotations

import math
import time

import numpy as np
import zenoh

from kinematics.model import RobotModel
from learner.model import ErrorModel
from stream.compensation import CompensationReply
from stream.dashboard import Dashboard, PointBatch
from stream.log import JsonLogger
from stream.points import point_arrays
from stream.stages._base import Stage
from stream.stages.compensation_service import adopt
from stream.trust import ModelGate, ModelTrustConfig
from stream.worker import Received
from wire import (
    DataPoint,
    Diagnostics,
    Metrics,
    RejectedMessageError,
    decode,
    split_key,
)

#: The longest a point waits to be drawn (s) once the points before it have been.
POINTS_EVERY_S = 1.0


class DashboardStage(Stage):
    """Logs learner metrics, stage drops, compensation answers, and new points with the
    prediction of the model the stage holds when they arrive (the lagging model)."""

    name = "dashboard"

    def __init__(
        self,
        session: zenoh.Session,
        cell: str,
        robot: str,
        dashboard: Dashboard,
        robot_model: RobotModel,
        T_W_0: np.ndarray | None = None,
        logger: JsonLogger | None = None,
        trust: ModelTrustConfig | None = None,
    ) -> None:
        super().__init__(session, cell, robot, logger)
        self.dashboard, self.robot_model, self.T_W_0 = dashboard, robot_model, T_W_0
        self.gate = ModelGate(robot, robot_model.description, trust)
        self.model: ErrorModel | None = None
        self._pending: list[tuple[DataPoint, float]] = []
        self._shape: tuple | None = None
        self._drawn_t = -math.inf  # when points were last drawn (monotonic s)
        for stream in ("metrics", "points", "model", "diagnostics", "compensate"):
            self.subscribe(stream)

    def handle(self, item: Received) -> None:
        stream, t = split_key(item.key)[2], item.received_t
        if stream == "metrics":
            self.dashboard.log_metrics(decode(item.payload, Metrics), t)
        elif stream == "points":
            self._pending.append((self._fits(decode(item.payload, DataPoint)), t))
        elif stream == "diagnostics":
            self.dashboard.log_diagnostics(decode(item.payload, Diagnostics), t)
        elif stream == "compensate":
            self.dashboard.log_compensation(decode(item.payload, CompensationReply), t)
        else:
            adopted = adopt(self, self.gate, item.payload)
            if adopted is None:
                return
            self._log_points()  # points before this model are judged by the previous one
            self.model = adopted[1]
        self.counter.accept()

    def _fits(self, p: DataPoint) -> DataPoint:
        """``p`` when it fits the robot and the points before it; ``invalid`` otherwise."""
        n = self.robot_model.description.n_joints
        if len(p.q) != n or (p.qs is not None and len(p.qs) != n):
            raise RejectedMessageError("invalid", f"point seq {p.seq}: not {n} joints")
        if p.frame == "tracker" and self.T_W_0 is None:
            raise RejectedMessageError("invalid", "point in the tracker frame without T_W_0")
        shape = (p.frame, p.qs is None, p.temperature_names)
        if self._shape is None:
            self._shape = shape
        elif shape != self._shape:
            raise RejectedMessageError("invalid", f"point seq {p.seq}: {shape} != {self._shape}")
        return p

    def on_idle(self, now: float) -> None:
        tick = time.monotonic()  # not ``now``: a wall clock set back must not hold points
        if self._pending and tick - self._drawn_t >= POINTS_EVERY_S:
            self._drawn_t = tick
            self._log_points()

    def _log_points(self) -> None:
        if not self._pending:
            return
        pending, self._pending = self._pending, []
        points = [p for p, _ in pending]
        arrays = point_arrays(points, self.T_W_0)
        prediction = None
        if self.model is not None:
            prediction = self.model.predict(arrays.features(self.model.spec))
        self.dashboard.log_points(
            PointBatch(
                seq=np.array([p.seq for p in points]),
                received_t=np.array([t for _, t in pending]),
                q=arrays.q,
                temperature_names=arrays.temperature_names,
                temperatures=arrays.temperatures,
                positions_m=arrays.T_0_S[:, :3, 3],
                errors_m=arrays.labels(self.robot_model),
                prediction=prediction,
            )
        )

    def finish(self) -> None:
        self._log_points()
        self.dashboard.flush()
