"""The Rerun dashboard writes an .rrd that reads back with its series and 3-D entities."""

import socket

import numpy as np
import pytest
from rerun.chunk import RrdReader

from kinematics.description import load_description
from kinematics.model import RobotModel
from stream.bus import free_port
from stream.dashboard import Dashboard, blueprint, error_colors, link_positions, read_scalars
from stream.messages import Metrics


def metrics(v: int) -> Metrics:
    return Metrics(
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


def test_rrd_holds_error_and_uncertainty_series(tmp_path):
    robot = RobotModel(load_description("ur10"))
    dash = Dashboard(robot)
    path = tmp_path / "d.rrd"
    dash.save(path)
    rng = np.random.default_rng(0)
    for v in (1, 2, 3):
        dash.log_metrics(metrics(v))
        errors = rng.normal(0, 1e-3, (4, 6))
        dash.log_points(
            np.arange(4) + 4 * v, np.zeros((4, 6)), rng.normal(0, 1, (4, 3)), errors, errors * 0.5
        )
    dash.close()
    series = read_scalars(path)
    t, mean = series["/metrics/test_error/mean"]
    np.testing.assert_array_equal(t, [1, 2, 3])
    np.testing.assert_allclose(mean[:, 0], [1.0, 0.5, 1 / 3])
    for name in ("epistemic", "aleatoric", "epistemic_p90"):
        assert len(series[f"/metrics/uncertainty/{name}"][1]) == 3
    t, band = series["/metrics/uncertainty/epistemic_band"]
    assert band.shape == (3, 2)
    t, per_point = series["/points/prediction_error"]
    assert list(t) == list(range(4, 16)) and np.all(per_point > 0)
    entities = {c.entity_path for c in RrdReader(str(path)).stream()}
    assert {"/world/points", "/world/errors", "/world/robot", "/metrics/memory/age"} <= entities
    assert RrdReader(str(path)).blueprints()


def test_links_end_at_the_tool_and_colours_saturate():
    robot = RobotModel(load_description("ur10"))
    q = np.array([0.1, -1.0, 1.2, 0.3, 0.5, 0.0])
    links = link_positions(robot, q)
    np.testing.assert_allclose(links[-1], robot.fk(q[None])[0, :3, 3], atol=1e-12)
    c = error_colors(np.array([0.0, 1.0, 5.0]), scale_mm=2.0)
    assert c[0].tolist() == [0, 255, 0] and c[2].tolist() == [255, 0, 0]
    assert blueprint() is not None


@pytest.mark.parametrize("value", [float("nan")])
def test_metrics_with_nan_before_a_test_set_are_logged(tmp_path, value):
    dash = Dashboard(RobotModel(load_description("ur10")))
    dash.save(tmp_path / "n.rrd")
    dash.log_metrics(Metrics(**{**metrics(1).__dict__, "test_mean_mm": value}))
    dash.close()
    assert np.isnan(read_scalars(tmp_path / "n.rrd")["/metrics/test_error/mean"][1][0, 0])


@pytest.mark.integration
def test_serve_opens_the_web_viewer_and_grpc_ports():
    dash = Dashboard(RobotModel(load_description("ur10")))
    web, grpc = free_port(), free_port()
    url = dash.serve(web_port=web, grpc_port=grpc)
    assert url.endswith(f":{grpc}/proxy")
    dash.log_metrics(metrics(1))
    for port in (web, grpc):
        socket.create_connection(("127.0.0.1", port), timeout=5).close()
    dash.close()
