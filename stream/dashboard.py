"""The Rerun dashboard: learning curves, per-point errors with their bands, the stream's inputs,
drops, compensation answers, and the robot with its errors.

Every entity is logged on two timelines: ``time`` (wall clock when the dashboard received the
message) and ``point`` (the newest data point's ``seq`` at that moment), so every panel shows
its data on either; the viewer opens on ``time``. Entities (mm unless named):

- ``metrics/test_error/{mean,max}`` (held-out test points, newest model),
  ``metrics/batch_error/mean``, ``metrics/uncertainty/{aleatoric,epistemic,epistemic_p90}``
  (std), ``metrics/memory/size``, ``metrics/memory/age`` (bar chart: memory points per batch
  age), ``metrics/model/version``, ``metrics/{quarantined,withheld}`` (points the learner's
  quarantine kept out, updates its publish gate withheld; cumulative)
- ``points/error/{measured,predicted,interval,epistemic}``: each point's position error and
  the lagging model's prediction of it, with its 90 % predictive and epistemic bands
  (``interval`` and ``epistemic`` hold two series, lower and upper)
- ``points/left/{error,interval,epistemic}``: what is left of each point's error after the
  lagging model's prediction (the model before it learned the point), with its bands
- ``coverage/interval_90``: fraction of measured components inside the 90 % interval over the
  last ``coverage_window`` points, beside the nominal 0.9
- ``inputs/joints`` (deg), ``inputs/temperatures`` (°C), ``drops/<stage>/<reason>`` (counts)
- ``compensation/{correction,residual,epistemic,trusted}``: each answer of the service
- ``world/robot/{links,joints,tool}`` (``stream.dashboard_robot``, at the newest point),
  ``world/points`` (the newest ``max_points`` measured positions coloured by what is left of
  their error, redrawn every ``cloud_every`` points), ``world/errors`` (measured error arrows,
  scaled by ``arrow_scale``, coloured as their points)

Sinks, set together by ``open``: an .rrd file, a served recording with a web viewer
(:func:`viewer_url` opens it live), a running viewer.
"""

from __future__ import annotations

import time
from dataclasses import dataclass
from pathlib import Path
from urllib.parse import quote

import numpy as np
import rerun as rr
from rerun.chunk import RrdReader

from kinematics.model import RobotModel
from learner.evidential import Evidential
from stream.compensation import CompensationReply
from stream.dashboard_layout import SERIES_STYLE, TIMELINE, blueprint
from stream.dashboard_robot import reach_m, robot_archetypes
from stream.dashboard_scores import error_colors, rolling_coverage, score_points
from wire import Diagnostics, Metrics

APPLICATION_ID = "robocal"
#: Most named series in one recording (drop reasons come from messages: a bound on entities).
MAX_SERIES = 200
RAD_TO_DEG = 180.0 / np.pi


def viewer_url(host: str, web_port: int, grpc_port: int) -> str:
    """The web viewer's address that opens the live recording served on ``grpc_port``."""
    grpc = f"rerun+http://{host}:{grpc_port}/proxy"
    return f"http://{host}:{web_port}/?url={quote(grpc, safe='')}"


@dataclass(frozen=True, kw_only=True)
class PointBatch:
    """New data points as the dashboard draws them: ``seq``, receive time (s since 1970),
    controller joint angles ``q`` (rad), temperatures (°C, by ``temperature_names``),
    base-frame positions (m), measured pose errors ``(N, 6)`` (m, rad), and the lagging
    model's prediction of those errors (None before the first model)."""

    seq: np.ndarray
    received_t: np.ndarray
    q: np.ndarray
    temperature_names: tuple[str, ...]
    temperatures: np.ndarray
    positions_m: np.ndarray
    errors_m: np.ndarray
    prediction: Evidential | None


class Dashboard:
    """One Rerun recording of one robot's pipeline; log calls are cheap and thread-safe."""

    def __init__(
        self,
        robot: RobotModel,
        recording_id: str = "robocal",
        arrow_scale: float = 50.0,
        max_points: int = 5000,
        cloud_every: int = 100,
        coverage_window: int = 200,
        seed: int = 0,
    ) -> None:
        self.robot = robot
        self.arrow_scale, self.max_points, self.cloud_every = arrow_scale, max_points, cloud_every
        self._unseen = 0  # points not yet drawn in the cloud
        self.coverage_window, self.seed = coverage_window, seed
        self.rec = rr.RecordingStream(APPLICATION_ID, recording_id=recording_id)
        self.rec.set_log_time_enabled(False)  # the two timelines below are the only ones
        self.rec.set_log_tick_enabled(False)
        self.point = 0
        self._positions = np.zeros((0, 3))
        self._errors = np.zeros((0, 3))
        self._left_mm = np.zeros(0)
        self._inside = np.zeros(0)
        self._named: set[str] = set()
        self._reach = reach_m(robot)  # m: sizes in the 3-D view follow the robot
        self.blueprint = blueprint(self._reach)

    # sinks

    def open(
        self,
        rrd: str | Path | None = None,
        serve: tuple[int, int, str] | None = None,
        connect: str | None = None,
    ) -> str | None:
        """Send from now on to every sink at once: an .rrd file, a served recording with a web
        viewer (``(web_port, grpc_port, host)``, ``host`` being how browsers reach this
        machine), a running viewer (``connect``: its URL, ``""`` for this machine's). Rerun
        replaces a recording's sinks on each call, so they are set together, once. Returns the
        one URL that opens the served recording (None when not served)."""
        sinks: list = []
        if rrd is not None:
            Path(rrd).parent.mkdir(parents=True, exist_ok=True)
            sinks.append(rr.FileSink(str(rrd)))
        if serve is not None:
            sinks.append(rr.GrpcServerSink(port=serve[1]))
        if connect is not None:
            sinks.append(rr.GrpcSink(connect or None))
        self.rec.set_sinks(*sinks, default_blueprint=self.blueprint)
        for path, style in SERIES_STYLE.items():  # a sink gets only what is logged after it
            self._style(path, **style)
        self.rec.log("world", rr.ViewCoordinates.RIGHT_HAND_Z_UP, static=True)
        if serve is None:
            return None
        web_port, grpc_port, host = serve
        rr.serve_web_viewer(web_port=web_port, open_browser=False)
        return viewer_url(host, web_port, grpc_port)

    def save(self, path: str | Path) -> None:
        """Only an .rrd file (see :meth:`open` for several sinks)."""
        self.open(rrd=path)

    def serve(self, web_port: int = 9090, grpc_port: int = 9876, host: str = "localhost") -> str:
        """Only a served recording and web viewer; the URL that opens it (see :meth:`open`)."""
        return self.open(serve=(web_port, grpc_port, host))

    # time

    def _at(self, t: float) -> None:
        self.rec.set_time(TIMELINE, timestamp=t)
        self.rec.set_time("point", sequence=self.point)

    def _style(self, path: str, kind: str = "lines", **style) -> None:
        """Names and colours of an entity's series, once, static (kept on every timeline)."""
        if path not in self._named:
            self._named.add(path)
            series = rr.SeriesPoints if kind == "points" else rr.SeriesLines
            self.rec.log(path, series(**style), static=True)

    def _columns(self, path: str, seq: np.ndarray, t: np.ndarray, values: np.ndarray) -> None:
        values = np.asarray(values, dtype=float)
        self.rec.send_columns(
            path,
            indexes=[
                rr.TimeColumn(TIMELINE, timestamp=t),
                rr.TimeColumn("point", sequence=seq),
            ],
            columns=rr.Scalars.columns(scalars=values.reshape(len(seq), -1)),
        )

    # messages

    def log_metrics(self, m: Metrics, received_t: float | None = None) -> None:
        """One learner update, at its receive time (s since 1970; now by default)."""
        self._at(time.time() if received_t is None else received_t)
        log = self.rec.log
        log("metrics/test_error/mean", rr.Scalars(m.test_mean_mm))
        log("metrics/test_error/max", rr.Scalars(m.test_max_mm))
        log("metrics/batch_error/mean", rr.Scalars(m.batch_mean_mm))
        log("metrics/uncertainty/aleatoric", rr.Scalars(m.aleatoric_mm))
        log("metrics/uncertainty/epistemic", rr.Scalars(m.epistemic_mm))
        log("metrics/uncertainty/epistemic_p90", rr.Scalars(m.epistemic_p90_mm))
        log("metrics/memory/size", rr.Scalars(float(m.memory_size)))
        if m.memory_age:
            log("metrics/memory/age", rr.BarChart(np.asarray(m.memory_age, dtype=float)))
        log("metrics/model/version", rr.Scalars(float(m.model_version)))
        for name in ("quarantined", "withheld"):  # learner counts, where the learner has them
            value = getattr(m, name, None)
            if value is not None:
                log(f"metrics/{name}", rr.Scalars(float(value)))

    def log_diagnostics(self, d: Diagnostics, received_t: float | None = None) -> None:
        """A stage's drop counts by reason and in ``all`` (counts since the stage started)."""
        self._at(time.time() if received_t is None else received_t)
        stage = rr.escape_entity_path_part(d.stage)
        counts = {"all": sum(d.dropped.values()), **d.dropped}
        for reason, n in counts.items():
            path = f"drops/{stage}/{rr.escape_entity_path_part(reason)}"
            if path not in self._named and len(self._named) >= MAX_SERIES:
                continue  # a flood of made-up stages or reasons draws no more series
            self._style(path, names=[f"{d.stage}: {reason}"])
            self.rec.log(path, rr.Scalars(float(n)))

    def log_compensation(self, reply: CompensationReply, received_t: float | None = None) -> None:
        """One compensation answer: predicted correction and epistemic std of the position
        (mm), the corrected command's solver residual (mm), trusted (1) or not (0)."""
        self._at(time.time() if received_t is None else received_t)
        log = self.rec.log
        log("compensation/correction", rr.Scalars(float(np.linalg.norm(reply.error[:3]) * 1e3)))
        log("compensation/residual", rr.Scalars(reply.residual_m * 1e3))
        log(
            "compensation/epistemic",
            rr.Scalars(float(np.linalg.norm(np.sqrt(reply.epistemic[:3])) * 1e3)),
        )
        log("compensation/trusted", rr.Scalars(float(reply.trusted)))

    def log_points(self, b: PointBatch) -> None:
        """New data points: per-point series on both timelines, then the 3-D cell."""
        if len(b.seq) == 0:
            return
        seq, t = np.asarray(b.seq, dtype=np.int64), np.asarray(b.received_t, dtype=float)
        s = score_points(b.errors_m, b.prediction, seed=self.seed + int(seq[0]))
        col = self._columns
        col("points/error/measured", seq, t, s.measured_mm)
        col("points/left/error", seq, t, s.left_mm)
        if s.predicted_mm is not None:
            col("points/error/predicted", seq, t, s.predicted_mm)
            col("points/error/interval", seq, t, s.predicted_band_mm)
            col("points/error/epistemic", seq, t, s.predicted_epistemic_mm)
            col("points/left/interval", seq, t, s.left_band_mm)
            col("points/left/epistemic", seq, t, s.left_epistemic_mm)
            cov = rolling_coverage(self._inside, s.inside, self.coverage_window)
            self._inside = np.concatenate([self._inside, s.inside.mean(axis=1)])
            self._inside = self._inside[-self.coverage_window :]
            col("coverage/interval_90", seq, t, np.column_stack([cov, np.full(len(cov), 0.9)]))
        n = self.robot.description.n_joints
        self._style("inputs/joints", names=[f"J{i}" for i in range(1, n + 1)])
        col("inputs/joints", seq, t, np.asarray(b.q, dtype=float) * RAD_TO_DEG)
        if b.temperature_names:
            self._style("inputs/temperatures", names=list(b.temperature_names))
            col("inputs/temperatures", seq, t, b.temperatures)
        self.point = max(self.point, int(seq.max()))
        self._log_world(b, s.left_mm, t.max())

    def _log_world(self, b: PointBatch, left_mm: np.ndarray, t: float) -> None:
        keep = self.max_points
        self._positions = np.concatenate([self._positions, b.positions_m])[-keep:]
        self._errors = np.concatenate([self._errors, b.errors_m[:, :3]])[-keep:]
        self._left_mm = np.concatenate([self._left_mm, left_mm])[-keep:]
        self._unseen += len(left_mm)
        self._at(t)
        for name, archetype in robot_archetypes(self.robot, b.q[-1]).items():
            self.rec.log(f"world/robot/{name}", archetype)
        if self._unseen >= self.cloud_every:
            self._log_cloud()

    def _log_cloud(self) -> None:
        """The newest ``max_points`` points and error arrows, coloured by what is left of their
        error (green 0 to red at the 95th percentile): a whole cloud, so only every
        ``cloud_every`` new points (a cloud per batch would grow the recording quadratically)."""
        self._unseen = 0
        if len(self._left_mm) == 0:
            return
        colors = error_colors(self._left_mm, float(np.percentile(self._left_mm, 95)))
        r = self._reach
        self.rec.log("world/points", rr.Points3D(self._positions, colors=colors, radii=0.004 * r))
        self.rec.log(
            "world/errors",
            rr.Arrows3D(
                origins=self._positions,
                vectors=self._errors * self.arrow_scale,
                colors=colors,
                radii=0.001 * r,
            ),
        )

    def flush(self) -> None:
        """Draw the points not yet in the cloud, and send what is buffered."""
        if self._unseen:
            self._log_cloud()
        self.rec.flush()

    def close(self) -> None:
        """Flush and finish the sinks (the .rrd gets its footer)."""
        self.flush()
        self.rec.disconnect()


def read_scalars(
    path: str | Path, timeline: str = "point"
) -> dict[str, tuple[np.ndarray, np.ndarray]]:
    """The scalar series of an .rrd: entity path -> (``timeline`` index: ``point`` seq or
    ``time`` as datetime64, values ``(T, k)``)."""
    parts: dict[str, list[tuple[np.ndarray, list]]] = {}
    for chunk in RrdReader(str(path)).stream():
        batch = chunk.to_record_batch()
        if "Scalars:scalars" not in batch.schema.names or chunk.is_static:
            continue
        parts.setdefault(chunk.entity_path, []).append(
            (
                batch.column(timeline).to_numpy(zero_copy_only=False),
                batch.column("Scalars:scalars").to_pylist(),
            )
        )
    out = {}
    for entity, chunks in parts.items():
        t = np.concatenate([c[0] for c in chunks])
        v = np.concatenate([np.asarray(c[1], dtype=float) for c in chunks])
        order = np.argsort(t, kind="stable")
        out[entity] = (t[order], v[order])
    return out
