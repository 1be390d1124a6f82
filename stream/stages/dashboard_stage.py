"""The dashboard stage: metrics, points and models of one robot into a Rerun recording."""

from __future__ import annotations

import numpy as np
import zenoh

from kinematics.model import RobotModel
from learner.features import dataset_features, dataset_labels
from learner.model import ErrorModel
from learner.snapshot import snapshot_from_bytes
from stream.bus import Received
from stream.dashboard import Dashboard
from stream.log import JsonLogger
from stream.messages import DataPoint, Metrics, decode, decode_model, split_key
from stream.points import points_to_dataset
from stream.stages._base import Stage


class DashboardStage(Stage):
    """Logs learner metrics, and new points with the current model's prediction error."""

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
    ) -> None:
        super().__init__(session, cell, robot, logger)
        self.dashboard, self.robot_model, self.T_W_0 = dashboard, robot_model, T_W_0
        self.model: ErrorModel | None = None
        self._pending: list[DataPoint] = []
        for stream in ("metrics", "points", "model"):
            self.subscribe(stream)

    def handle(self, item: Received) -> None:
        stream = split_key(item.key)[2]
        if stream == "metrics":
            self.dashboard.log_metrics(decode(item.payload, Metrics))
        elif stream == "points":
            self._pending.append(decode(item.payload, DataPoint))
        else:
            self._log_points()  # points before this model are judged by the previous one
            self.model = snapshot_from_bytes(decode_model(item.payload)[1])
        self.counter.accept()

    def on_idle(self, now: float) -> None:
        self._log_points()

    def _log_points(self) -> None:
        if not self._pending:
            return
        points, self._pending = self._pending, []
        ds = points_to_dataset(points, self.robot_model.description.name, self.T_W_0)
        errors = dataset_labels(ds, self.robot_model)
        predicted = None
        if self.model is not None:
            predicted = self.model.predict(dataset_features(ds, self.model.spec)).mean
        self.dashboard.log_points(
            np.array([p.seq for p in points]),
            ds.q(),
            ds.measured_poses_base()[:, :3, 3],
            errors,
            predicted,
        )

    def finish(self) -> None:
        self._log_points()
        self.dashboard.flush()
