"""The URL the dashboard prints, opened in headless Chromium, shows the live recording.

The dashboard serves a recording (robot, per-point errors with bands, metrics) exactly as the
daemon does with ``serve = true``; playwright drives Debian's ``chromium`` to the printed URL.
Rerun's viewer draws into one canvas, so the check is what is on screen: the robot's link
colour and the error series' colour (both drawn only from received data), and the viewer's
requests to the recording's gRPC address. The same page without the recording address (the
address printed before) makes no such request and shows neither colour.
"""

import importlib.util
import time

import numpy as np
import pytest

from kinematics.description import load_description
from kinematics.model import RobotModel
from learner.evidential import Evidential
from stream.bus import free_port
from stream.dashboard import Dashboard, PointBatch
from stream.dashboard_view import ViewerCheck, find_chromium, open_viewer
from wire import Diagnostics, Metrics

CHROMIUM = find_chromium()
VIEWPORT = (1200, 750)  # smaller than a screen: the software rasterizer draws it faster
pytestmark = [
    pytest.mark.integration,
    pytest.mark.skipif(
        CHROMIUM is None, reason="needs Debian's chromium (apt-get install chromium; .ci/run)"
    ),
    pytest.mark.skipif(
        importlib.util.find_spec("playwright") is None,
        reason="needs playwright (pip install -c constraints.txt -e '.[dev]')",
    ),
]


def fill(dash: Dashboard, rounds: int = 4, n: int = 25) -> None:
    """Points with a lagging model's prediction, metrics and drops, as a pipeline logs them."""
    rng = np.random.default_rng(0)
    for k in range(rounds):
        errors = rng.normal(0, 1e-3, (n, 6))
        ones = np.ones((n, 6))
        prediction = Evidential(gamma=0.8 * errors, nu=ones, alpha=4 * ones, beta=2e-7 * ones)
        dash.log_points(
            PointBatch(
                seq=np.arange(k * n, (k + 1) * n),
                received_t=time.time() + np.arange(n) * 0.05,
                q=rng.uniform(-1.5, 1.5, (n, 6)),
                temperature_names=("ambient",),
                temperatures=rng.normal(22, 0.5, (n, 1)),
                positions_m=rng.uniform(-1, 1, (n, 3)) + [0.5, 0, 0.8],
                errors_m=errors,
                prediction=prediction if k else None,
            )
        )
        dash.log_metrics(
            Metrics(
                model_version=k + 1,
                n_seen=(k + 1) * n,
                memory_size=n,
                train_time_s=0.1,
                test_mean_mm=1.0 / (k + 1),
                test_max_mm=2.0 / (k + 1),
                batch_mean_mm=1.1 / (k + 1),
                aleatoric_mm=0.3,
                epistemic_mm=0.2,
                epistemic_p90_mm=0.4,
            )
        )
        dash.log_diagnostics(Diagnostics(stage="window", accepted=n * (k + 1), dropped={}))
    dash.flush()


@pytest.fixture(scope="module")
def served(tmp_path_factory):
    dash = Dashboard(RobotModel(load_description("ur10")))
    web, grpc = free_port(), free_port()
    rrd = tmp_path_factory.mktemp("browser") / "d.rrd"
    url = dash.open(rrd=rrd, serve=(web, grpc, "localhost"))  # file and server, as the daemon
    fill(dash)
    yield url, web, grpc
    dash.close()


def test_the_printed_url_opens_the_live_recording(served):
    url, _, grpc = served
    check = open_viewer(url, f":{grpc}/", CHROMIUM, timeout_s=120, viewport=VIEWPORT)
    assert check.grpc_requests >= 1, check.console_errors
    assert check.robot_pixels >= 200 and check.series_pixels >= 200, (
        check.robot_pixels,
        check.series_pixels,
        check.console_errors,
    )
    assert check.seconds_to_data is not None


def test_the_viewer_without_the_recording_address_shows_no_data(served):
    _, web, grpc = served
    drawn: list[float] = []

    def viewer_drawn_3_s_ago(check: ViewerCheck) -> bool:
        if check.colours > 50:  # the viewer's own interface is on screen
            drawn.append(time.monotonic())
        return bool(drawn) and time.monotonic() - drawn[0] >= 3.0

    check = open_viewer(
        f"http://localhost:{web}/",
        f":{grpc}/",
        CHROMIUM,
        120,
        until=viewer_drawn_3_s_ago,
        viewport=VIEWPORT,
    )
    assert drawn, "the viewer never drew its interface"
    assert check.grpc_requests == 0
    assert check.robot_pixels < 50 and check.series_pixels < 50
    assert check.seconds_to_data is None
