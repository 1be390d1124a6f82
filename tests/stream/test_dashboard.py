"""The Rerun dashboard: what it writes to an .rrd, its bands and coverage, the robot's solid
geometry, and the one URL that opens a served recording."""

import queue
import signal
import socket
import subprocess
import sys
import threading
import time
from dataclasses import replace
from pathlib import Path
from urllib.parse import parse_qs, urlparse

import numpy as np
import pytest
from rerun.chunk import RrdReader
from scipy import stats
from scipy.spatial.transform import Rotation

from kinematics.description import load_description
from kinematics.model import RobotModel
from learner.evidential import Evidential
from stream.bus import BusConfig, free_port, open_session
from stream.compensation import CompensationReply
from stream.dashboard import MAX_SERIES, Dashboard, PointBatch, read_scalars, viewer_url
from stream.dashboard_robot import robot_archetypes, segments, skeleton, z_to
from stream.dashboard_scores import error_colors, norm_band, rolling_coverage, score_points
from stream.stages.dashboard_stage import POINTS_EVERY_S, DashboardStage
from tests.stream.conftest import wait_subscribed
from tests.stream.wire_examples import POINT
from wire import Diagnostics, Metrics, encode, key

UR10 = RobotModel(load_description("ur10"))


def metrics(v: int, **extra) -> Metrics:
    fields = dict(
        model_version=v,
        n_seen=50 * v,
        memory_size=40,
        train_time_s=0.5,
        test_mean_mm=1.0 / v,
        test_max_mm=3.0 / v,
        batch_mean_mm=1.2 / v,
        aleatoric_mm=0.2,
        epistemic_mm=0.5 / v,
        epistemic_p90_mm=0.9 / v,
        memory_age=(20, 10, 10),
    )
    return Metrics(**fields, **extra)


def evidential(mean: np.ndarray, scale_m: float = 1e-3) -> Evidential:
    """A NIG prediction with Student-t scale ``scale_m`` and 2 alpha = 8 degrees of freedom."""
    n = len(mean)
    nu, alpha = np.full((n, 6), 1.0), np.full((n, 6), 4.0)
    return Evidential(gamma=mean, nu=nu, alpha=alpha, beta=np.full((n, 6), 2.0 * scale_m**2))


def batch(first: int, n: int, rng, prediction: bool) -> PointBatch:
    errors = rng.normal(0, 1e-3, (n, 6))
    return PointBatch(
        seq=np.arange(first, first + n),
        received_t=time.time() + np.arange(n) * 0.1,
        q=rng.uniform(-1, 1, (n, 6)),
        temperature_names=("ambient", "j2_motor"),
        temperatures=rng.normal(22, 1, (n, 2)),
        positions_m=rng.normal(0, 1, (n, 3)),
        errors_m=errors,
        prediction=evidential(errors * 0.5) if prediction else None,
    )


def test_rrd_holds_every_trace_on_both_timelines(tmp_path):
    dash = Dashboard(UR10)
    path = tmp_path / "d.rrd"
    dash.save(path)
    rng = np.random.default_rng(0)
    for v in (1, 2, 3):
        dash.log_points(batch(4 * v, 4, rng, prediction=v > 1))
        dash.log_metrics(metrics(v, quarantined=v - 1, withheld=v // 2))
        dash.log_diagnostics(Diagnostics(stage="window", accepted=10, dropped={"late": v}))
    reply = CompensationReply(
        model_version=3,
        error=(3e-4, 4e-4, 0.0, 0.0, 0.0, 0.0),
        lo=(0.0,) * 6,
        hi=(0.0,) * 6,
        level=0.9,
        aleatoric=(0.0,) * 6,
        epistemic=(1e-8, 0.0, 0.0, 0.0, 0.0, 0.0),
        q_corrected=(0.0,) * 6,
        iterations=3,
        residual_m=2e-6,
        trusted=True,
    )
    dash.log_compensation(reply)
    dash.close()
    s = read_scalars(path)
    t, mean = s["/metrics/test_error/mean"]
    assert list(t) == [7, 11, 15]  # the newest point seq when each update arrived
    np.testing.assert_allclose(mean[:, 0], [1.0, 0.5, 1 / 3])
    np.testing.assert_array_equal(s["/metrics/quarantined"][1][:, 0], [0, 1, 2])
    np.testing.assert_array_equal(s["/metrics/withheld"][1][:, 0], [0, 1, 1])
    np.testing.assert_array_equal(s["/drops/window/late"][1][:, 0], [1, 2, 3])
    np.testing.assert_array_equal(s["/drops/window/all"][1][:, 0], [1, 2, 3])
    np.testing.assert_allclose(s["/compensation/correction"][1][0, 0], 0.5)
    np.testing.assert_allclose(s["/compensation/residual"][1][0, 0], 2e-3)
    np.testing.assert_allclose(s["/compensation/epistemic"][1][0, 0], 0.1)
    assert list(s["/points/left/error"][0]) == list(range(4, 16))
    assert list(s["/points/error/interval"][0]) == list(range(8, 16))  # from the first model
    assert s["/inputs/temperatures"][1].shape == (12, 2)
    assert s["/coverage/interval_90"][1].shape == (8, 2)
    for chunk in RrdReader(str(path)).stream():
        if not chunk.is_static:
            assert sorted(chunk.timeline_names) == ["point", "time"], chunk.entity_path
    entities = {c.entity_path for c in RrdReader(str(path)).stream()}
    assert {"/world/points", "/world/errors", "/world/robot/links", "/world/robot/joints"} <= (
        entities
    )


def test_a_flood_of_drop_reasons_draws_a_bounded_number_of_series(tmp_path):
    dash = Dashboard(UR10)
    dash.save(tmp_path / "f.rrd")
    flood = {f"made_up_{i}": 1 for i in range(3 * MAX_SERIES)}
    dash.log_diagnostics(Diagnostics(stage="window", accepted=0, dropped=flood))
    dash.close()
    drops = [e for e in read_scalars(tmp_path / "f.rrd") if e.startswith("/drops/")]
    assert "/drops/window/all" in drops and 10 < len(drops) <= MAX_SERIES


def test_norm_band_matches_the_chi_distribution_and_student_t_is_wider():
    rng = np.random.default_rng(1)
    sigma = np.full((2, 3), 2.0)
    band = norm_band(np.zeros((2, 3)), sigma, None, 0.9, rng, n_draws=40_000)
    expected = 2.0 * np.sqrt(stats.chi2.ppf([0.05, 0.95], df=3))
    np.testing.assert_allclose(band, np.tile(expected, (2, 1)), rtol=0.03)
    heavy = norm_band(np.zeros((1, 3)), sigma[:1], np.full((1, 3), 3.0), 0.9, rng, 40_000)
    assert heavy[0, 1] > 1.1 * expected[1]
    far = norm_band(np.array([[100.0, 0, 0]]), np.ones((1, 3)), None, 0.9, rng, 40_000)
    np.testing.assert_allclose(far[0], 100.0 + stats.norm.ppf([0.05, 0.95]), atol=0.1)


def test_scores_of_a_perfect_prediction_and_rolling_coverage():
    e = np.random.default_rng(2).normal(0, 1e-3, (5, 6))
    s = score_points(e, evidential(e.copy()))
    np.testing.assert_allclose(s.left_mm, 0.0, atol=1e-12)
    np.testing.assert_allclose(s.predicted_mm, s.measured_mm)
    assert s.inside.all() and np.all(s.left_band_mm[:, 0] < s.left_band_mm[:, 1])
    assert score_points(e, None).predicted_mm is None
    inside = np.array([[1, 1, 1], [0, 0, 0], [1, 1, 0]], dtype=bool)
    cov = rolling_coverage(np.array([1.0, 0.0]), inside, window=3)
    np.testing.assert_allclose(cov, [2 / 3, 1 / 3, (1 + 0 + 2 / 3) / 3])


def test_robot_is_solid_links_ending_at_the_tool():
    q = np.array([0.1, -1.0, 1.2, 0.3, 0.5, 0.0])
    points, axes = skeleton(UR10, q)
    np.testing.assert_allclose(points[-1], UR10.fk(q[None])[0, :3, 3], atol=1e-12)
    np.testing.assert_allclose(np.linalg.norm(axes, axis=1), 1.0)
    start, length, quat = segments(points)
    assert np.isclose(length.sum(), np.linalg.norm(np.diff(points, axis=0), axis=1).sum())
    parts = robot_archetypes(UR10, q)
    assert set(parts) == {"links", "joints", "tool"}
    u = np.array([[0, 0, 1.0], [0, 0, -1.0], [1.0, 0, 0], [0.6, 0, 0.8]])
    np.testing.assert_allclose(Rotation.from_quat(z_to(u)).apply([0, 0, 1.0]), u, atol=1e-12)
    c = error_colors(np.array([0.0, 1.0, 5.0]), scale_mm=2.0)
    assert c[0].tolist() == [0, 255, 0] and c[2].tolist() == [255, 0, 0]


def test_viewer_url_carries_the_recording_address():
    url = urlparse(viewer_url("cell-pc", 9090, 9876))
    assert (url.scheme, url.netloc, url.path) == ("http", "cell-pc:9090", "/")
    assert parse_qs(url.query) == {"url": ["rerun+http://cell-pc:9876/proxy"]}


def test_metrics_with_nan_before_a_test_set_are_logged(tmp_path):
    dash = Dashboard(UR10)
    dash.save(tmp_path / "n.rrd")
    dash.log_metrics(Metrics(**{**metrics(1).__dict__, "test_mean_mm": float("nan")}))
    dash.close()
    assert np.isnan(read_scalars(tmp_path / "n.rrd")["/metrics/test_error/mean"][1][0, 0])


@pytest.mark.integration
def test_a_served_dashboard_still_writes_its_rrd(tmp_path):
    dash = Dashboard(UR10)
    web, grpc = free_port(), free_port()
    url = dash.open(rrd=tmp_path / "s.rrd", serve=(web, grpc, "127.0.0.1"))
    assert url == viewer_url("127.0.0.1", web, grpc)
    for v in (1, 2):
        dash.log_metrics(metrics(v))
    for port in (web, grpc):
        socket.create_connection(("127.0.0.1", port), timeout=5).close()
    dash.close()
    assert len(read_scalars(tmp_path / "s.rrd")["/metrics/test_error/mean"][0]) == 2
    styled = {c.entity_path for c in RrdReader(str(tmp_path / "s.rrd")).stream() if c.is_static}
    assert "/metrics/test_error/mean" in styled  # names and colours reach the file


@pytest.mark.integration
def test_a_burst_of_points_is_drawn_in_few_batches_and_none_is_lost(tmp_path):
    """Points that come faster than a drawing pays for wait up to ``POINTS_EVERY_S``: the
    stage's 0.2 s idle tick would otherwise draw a handful of points five times a second."""
    port = free_port()
    bus = open_session(BusConfig.loopback(port, listen=True))
    source = open_session(BusConfig.loopback(port, listen=False))
    dash = Dashboard(UR10)
    dash.open(rrd=tmp_path / "p.rrd")
    stage = DashboardStage(bus, "c", "ur10", dash, UR10)
    drawn: list[int] = []
    draw = dash.log_points
    dash.log_points = lambda b: (drawn.append(len(b.seq)), draw(b))[1]
    try:
        wait_subscribed(source, key("c", "ur10", "points"))
        start = time.monotonic()
        for i in range(40):
            source.put(key("c", "ur10", "points"), encode(replace(POINT, seq=i)))
            time.sleep(0.05)
        deadline = time.monotonic() + 10.0
        while sum(drawn) < 40 and time.monotonic() < deadline:
            time.sleep(0.05)
        elapsed = time.monotonic() - start
    finally:
        stage.close()
        source.close()
        bus.close()
        dash.close()
    assert sum(drawn) == 40
    assert 2 <= len(drawn) <= elapsed / POINTS_EVERY_S + 2, (drawn, elapsed)
    assert len(read_scalars(tmp_path / "p.rrd")["/points/error/measured"][0]) == 40


RUN_CONFIG = """
cell = "c"
checkpoint_dir = "{dir}"
[bus]
mode = "peer"
listen = ["tcp/127.0.0.1:{port}"]
multicast_scouting = false
[[robot]]
name = "ur10"
description = "ur10"
stages = ["dashboard"]
[dashboard]
serve = true
web_port = {web}
grpc_port = {grpc}
host = "127.0.0.1"
"""


@pytest.mark.integration
def test_robocal_run_prints_the_one_url_of_the_live_dashboard(tmp_path):
    web, grpc, port = free_port(), free_port(), free_port()
    config = tmp_path / "run.toml"
    config.write_text(RUN_CONFIG.format(dir=tmp_path, port=port, web=web, grpc=grpc))
    robocal = str(Path(sys.executable).with_name("robocal"))
    proc = subprocess.Popen([robocal, "run", "--config", str(config)], stderr=subprocess.PIPE)
    read: queue.Queue[str] = queue.Queue()  # stderr read beside, so a missing line cannot hang

    def pump() -> None:
        for line in proc.stderr:
            read.put(line.decode())

    threading.Thread(target=pump, daemon=True).start()
    try:
        lines = [read.get(timeout=60)]
        while not lines[-1].startswith("dashboard ur10:"):
            lines.append(read.get(timeout=60))
        assert lines[-1].strip() == f"dashboard ur10: {viewer_url('127.0.0.1', web, grpc)}", lines
        deadline = time.monotonic() + 60.0
        while True:  # the daemon serves what the line promised
            try:
                for p in (web, grpc):
                    socket.create_connection(("127.0.0.1", p), timeout=2).close()
                break
            except OSError:
                assert time.monotonic() < deadline and proc.poll() is None
                time.sleep(0.3)
    finally:
        proc.send_signal(signal.SIGTERM)
        code = proc.wait(30)
    assert code == 0
