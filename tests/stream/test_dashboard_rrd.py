"""The .rrd a running pipeline writes: every series on the one timeline the viewer opens on.

A short simulated campaign streams through the daemon's window, learner, compensation and
dashboard stages over loopback Zenoh. The source holds after ``GATE`` points until the
dashboard has adopted a model, so the later points are drawn with the lagging model's
prediction and bands whatever the machine's load. Compensation queries follow. The test then
reads the written .rrd back chunk by chunk.
"""

import os
import time
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
import torch
from rerun.chunk import RrdReader

from learner.config import ContinualConfig, ModelConfig, TrainConfig
from sim_sources.cell import simulate
from sim_sources.scenarios import get_scenario
from sim_sources.streaming import StreamingConfig
from stream.bus import BusConfig, free_port, open_session
from stream.daemon import Daemon
from stream.dashboard import read_scalars
from stream.demo import compensation_check, demo_config
from stream.learner_core import LearnerStageConfig
from stream.log import JsonLogger
from stream.mcap_io import SOURCE_STREAMS
from stream.sources import SimCellSource
from tests.stream.conftest import wait_subscribed
from wire import TrackerSample, key

pytestmark = pytest.mark.integration

N, GATE, CELL = 120, 70, "dash"
SMALL = LearnerStageConfig(
    model=ModelConfig(hidden_layers=1, neurons=24),
    train=TrainConfig(batch_size=16),
    continual=ContinualConfig(memory=60, batch=30, init=30, epochs_per_update=8, init_epochs=60),
)


class GatedSource(SimCellSource):
    """Streams as fast as possible, but holds before tracker sample ``GATE`` until ``ready()``."""

    def __init__(self, *args, ready, **kwargs) -> None:
        super().__init__(*args, **kwargs)
        self.ready = ready

    def samples(self):
        for s in super().samples():
            if isinstance(s, TrackerSample) and s.seq == GATE:
                deadline = time.monotonic() + 60.0
                while not self.ready() and time.monotonic() < deadline:
                    time.sleep(0.1)
            yield s


@pytest.fixture(scope="module")
def rrd(tmp_path_factory) -> Path:
    torch.set_num_threads(1)
    out = tmp_path_factory.mktemp("dashboard")
    ds = simulate(get_scenario("paper"), N, 0)
    robot, port = ds.meta.robot, free_port()
    cfg = demo_config(out, CELL, robot, np.asarray(ds.meta.T_W_0), port)
    cfg = replace(cfg, learner=SMALL, window=replace(cfg.window, batch_size=30))
    daemon = Daemon(cfg, logger=JsonLogger(stream=open(os.devnull, "w"))).start()  # noqa: SIM115
    dashboard = next(s for s in daemon.stages if s.name == "dashboard")
    session = open_session(BusConfig.loopback(port, listen=False))
    try:
        wait_subscribed(session, *(key(CELL, robot, s) for s in SOURCE_STREAMS))
        source = GatedSource(
            session,
            CELL,
            robot,
            ds,
            StreamingConfig(period_s=1.0),
            ready=lambda: dashboard.model is not None,
        )
        source.start()
        daemon.end_of_stream({robot: source.published})
        compensation_check(session, CELL, ds, 0, np.arange(9, N, 10)[:4])
        time.sleep(1.5)  # the stages' diagnostics (every second) reach the dashboard
    finally:
        session.close()
        daemon.stop()
    return Path(daemon.recordings[f"rrd/{robot}"])


def test_every_series_is_on_the_time_and_point_timelines(rrd):
    timelines, scalar_entities = set(), set()
    for chunk in RrdReader(str(rrd)).stream():
        if chunk.is_static:
            continue
        timelines.add(tuple(sorted(chunk.timeline_names)))
        if "Scalars:scalars" in chunk.to_record_batch().schema.names:
            scalar_entities.add(chunk.entity_path)
    assert timelines == {("point", "time")}
    assert len(scalar_entities) >= 25
    by_time = read_scalars(rrd, "time")
    by_point = read_scalars(rrd, "point")
    assert set(by_time) == set(by_point) == scalar_entities
    for entity, (t, _) in by_time.items():
        assert np.all(t > np.datetime64("2020-01-01")), entity  # wall clock, not source time


def test_the_viewer_opens_on_the_wall_clock_timeline(rrd):
    reader = RrdReader(str(rrd))
    (blueprint,) = reader.blueprints()
    timelines = [
        row["TimePanelBlueprint:timeline"]
        for chunk in reader.stream(store=blueprint)
        if chunk.entity_path == "/time_panel"
        for row in chunk.to_record_batch().to_pylist()
        if row.get("TimePanelBlueprint:timeline")
    ]
    assert timelines == [["time"]]


def test_coverage_temperature_and_the_new_traces_are_recorded(rrd):
    s = read_scalars(rrd)
    seq, temps = s["/inputs/temperatures"]
    assert temps.shape == (N, 15) and np.all((temps > 5) & (temps < 100))  # °C
    assert s["/inputs/joints"][1].shape == (N, 6)
    seq, cov = s["/coverage/interval_90"]
    assert 10 <= len(cov) <= N - GATE + 30 and np.all(seq >= GATE - 30)
    assert np.all((cov[:, 0] >= 0) & (cov[:, 0] <= 1)) and np.all(cov[:, 1] == 0.9)
    lower_upper = s["/points/error/interval"][1]
    assert len(lower_upper) == len(cov) and np.all(lower_upper[:, 0] < lower_upper[:, 1])
    left, band = s["/points/left/error"][1][:, 0], s["/points/left/interval"][1]
    assert len(left) == N and np.all(band[:, 0] >= 0)
    assert s["/metrics/model/version"][1][-1, 0] >= 2
    assert len(s["/compensation/correction"][1]) == 4
    assert np.all(s["/compensation/residual"][1] >= 0)
    stages = {e.split("/")[2] for e in s if e.startswith("/drops/") and e.endswith("/all")}
    assert {"window", "learner", "compensation", "dashboard"} <= stages
