"""The Rerun dashboard: learning curves, uncertainty, memory, and the robot with its errors.

Entities (timeline ``update`` = model version, ``point`` = data point seq):

- ``metrics/test_error/{mean,max}`` (mm), ``metrics/batch_error/mean`` (mm)
- ``metrics/uncertainty/{aleatoric,epistemic,epistemic_p90}`` (mm, std), a band for epistemic
- ``metrics/memory/size``, ``metrics/memory/age`` (bar chart: memory points per batch age),
  ``metrics/model/version``
- ``points/prediction_error`` (mm per point, prequential: the model before it saw the point)
- ``world/robot`` (links from FK), ``world/points`` (the newest ``max_points`` measured
  positions coloured by error), ``world/errors`` (error arrows, scaled by ``arrow_scale``)

Sinks: ``save`` an .rrd, ``serve`` a web viewer, or ``connect`` to a running viewer. The
blueprint opens with the time series on the left and the 3-D view on the right.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pinocchio as pin
import rerun as rr
import rerun.blueprint as rrb
from rerun.chunk import RrdReader

from kinematics.model import RobotModel
from stream.messages import Metrics

APPLICATION_ID = "robocal"


def blueprint() -> rrb.Blueprint:
    """Errors, uncertainty and memory over updates; per-point error; the 3-D cell view."""
    return rrb.Blueprint(
        rrb.Horizontal(
            rrb.Vertical(
                rrb.TimeSeriesView(
                    origin="/metrics",
                    contents=["metrics/test_error/**", "metrics/batch_error/**"],
                    name="Test error (mm)",
                ),
                rrb.TimeSeriesView(
                    origin="/metrics",
                    contents="metrics/uncertainty/**",
                    name="Uncertainty (mm, std)",
                ),
                rrb.TimeSeriesView(origin="/points", name="Per-point prediction error (mm)"),
                rrb.Horizontal(
                    rrb.TimeSeriesView(
                        origin="/metrics",
                        contents=["metrics/memory/size", "metrics/model/**"],
                        name="Memory and model version",
                    ),
                    rrb.BarChartView(origin="/metrics/memory/age", name="Memory by batch age"),
                ),
            ),
            rrb.Spatial3DView(origin="/world", name="Cell (base frame, m)"),
            column_shares=[3, 2],
        ),
        collapse_panels=True,
    )


def error_colors(error_mm: np.ndarray, scale_mm: float) -> np.ndarray:
    """RGB colours from green (0) through yellow to red (``>= scale_mm``)."""
    s = np.clip(np.asarray(error_mm, dtype=float) / max(scale_mm, 1e-9), 0.0, 1.0)
    r = np.clip(2.0 * s, 0.0, 1.0)
    g = np.clip(2.0 * (1.0 - s), 0.0, 1.0)
    return (np.stack([r, g, np.zeros_like(s)], axis=-1) * 255).astype(np.uint8)


def link_positions(robot: RobotModel, q_ctrl: np.ndarray) -> np.ndarray:
    """Joint origins and the tool point ``(n + 2, 3)`` (m, base frame) for a link polyline."""
    q = robot.description.to_dh(np.asarray(q_ctrl, dtype=float)[None])[0]
    pin.framesForwardKinematics(robot.model, robot.data, q)
    joints = [robot.data.oMi[i].translation.copy() for i in range(1, robot.model.njoints)]
    tool = robot.data.oMf[robot.model.getFrameId("tool")].translation.copy()
    return np.array([np.zeros(3), *joints, tool])


class Dashboard:
    """One Rerun recording of one robot's pipeline; log calls are cheap and thread-safe."""

    def __init__(
        self,
        robot: RobotModel,
        recording_id: str = "robocal",
        arrow_scale: float = 50.0,
        max_points: int = 5000,
    ) -> None:
        self.robot = robot
        self.arrow_scale = arrow_scale
        self.max_points = max_points
        self.rec = rr.RecordingStream(APPLICATION_ID, recording_id=recording_id)
        self._positions = np.zeros((0, 3))
        self._errors = np.zeros((0, 3))
        self._pred_mm = np.zeros(0)

    def save(self, path: str | Path) -> None:
        """Stream everything logged from now on into an .rrd file."""
        Path(path).parent.mkdir(parents=True, exist_ok=True)
        self.rec.save(str(path), default_blueprint=blueprint())

    def serve(self, web_port: int = 9090, grpc_port: int = 9876) -> str:
        """Serve a web viewer on ``web_port``; return the gRPC URL it reads from."""
        url = self.rec.serve_grpc(grpc_port=grpc_port, default_blueprint=blueprint())
        rr.serve_web_viewer(web_port=web_port, open_browser=False, connect_to=url)
        return url

    def connect(self, url: str | None = None) -> None:
        """Send to a running viewer (``rerun`` on this machine by default)."""
        self.rec.connect_grpc(url, default_blueprint=blueprint())

    def log_metrics(self, m: Metrics) -> None:
        """One learner update on the ``update`` timeline."""
        rec = self.rec
        rec.reset_time()
        rec.set_time("update", sequence=m.model_version)
        rec.log("metrics/test_error/mean", rr.Scalars(m.test_mean_mm))
        rec.log("metrics/test_error/max", rr.Scalars(m.test_max_mm))
        rec.log("metrics/batch_error/mean", rr.Scalars(m.batch_mean_mm))
        rec.log("metrics/uncertainty/aleatoric", rr.Scalars(m.aleatoric_mm))
        rec.log("metrics/uncertainty/epistemic", rr.Scalars(m.epistemic_mm))
        rec.log("metrics/uncertainty/epistemic_p90", rr.Scalars(m.epistemic_p90_mm))
        rec.log(
            "metrics/uncertainty/epistemic_band",
            rr.Scalars([0.0, m.epistemic_p90_mm]),
            rr.SeriesLines(names=["0", "p90"], widths=[0.5, 0.5]),
        )
        rec.log("metrics/memory/size", rr.Scalars(float(m.memory_size)))
        if m.memory_age:
            rec.log("metrics/memory/age", rr.BarChart(np.asarray(m.memory_age, dtype=float)))
        rec.log("metrics/model/version", rr.Scalars(float(m.model_version)))

    def log_points(
        self,
        seq: np.ndarray,
        q: np.ndarray,
        positions_m: np.ndarray,
        errors_m: np.ndarray,
        predicted_error_m: np.ndarray | None,
    ) -> None:
        """New measured points: base-frame positions, measured error vectors (m), and the
        current model's prediction of them (None before the first model)."""
        pred_mm = (
            np.linalg.norm(errors_m[:, :3], axis=1) * 1e3
            if predicted_error_m is None
            else np.linalg.norm(errors_m[:, :3] - predicted_error_m[:, :3], axis=1) * 1e3
        )
        self.rec.reset_time()
        for s, e in zip(seq, pred_mm, strict=True):
            self.rec.set_time("point", sequence=int(s))
            self.rec.log("points/prediction_error", rr.Scalars(float(e)))
        keep = self.max_points
        self._positions = np.concatenate([self._positions, positions_m])[-keep:]
        self._errors = np.concatenate([self._errors, errors_m[:, :3]])[-keep:]
        self._pred_mm = np.concatenate([self._pred_mm, pred_mm])[-keep:]
        self.rec.set_time("point", sequence=int(seq[-1]))
        self.rec.log(
            "world/points",
            rr.Points3D(
                self._positions,
                colors=error_colors(self._pred_mm, float(np.percentile(self._pred_mm, 95))),
                radii=0.01,
            ),
        )
        self.rec.log(
            "world/errors",
            rr.Arrows3D(origins=self._positions, vectors=self._errors * self.arrow_scale),
        )
        self.rec.log("world/robot", rr.LineStrips3D([link_positions(self.robot, q[-1])]))

    def flush(self) -> None:
        self.rec.flush()

    def close(self) -> None:
        """Flush and finish the sinks (the .rrd gets its footer)."""
        self.rec.flush()
        self.rec.disconnect()


def read_scalars(path: str | Path) -> dict[str, tuple[np.ndarray, np.ndarray]]:
    """The scalar series of an .rrd: entity path -> (sequence index, values ``(T, k)``)."""
    parts: dict[str, list[tuple[list, list]]] = {}
    for chunk in RrdReader(str(path)).stream():
        batch = chunk.to_record_batch()
        names = batch.schema.names
        if "Scalars:scalars" not in names:
            continue
        index = "update" if "update" in names else "point"
        parts.setdefault(chunk.entity_path, []).append(
            (batch.column(index).to_pylist(), batch.column("Scalars:scalars").to_pylist())
        )
    out = {}
    for entity, chunks in parts.items():
        t = np.concatenate([np.asarray(c[0]) for c in chunks])
        v = np.concatenate([np.asarray(c[1], dtype=float) for c in chunks])
        order = np.argsort(t, kind="stable")
        out[entity] = (t[order], v[order])
    return out
