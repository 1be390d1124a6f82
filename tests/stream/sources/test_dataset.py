"""The dataset source: a file streamed as a live cell joins back to exactly its own points
(settled check and event-time join of the window), the daemon builds it from ``[[sources]]``,
and a dataset or config it cannot stream is one line and exit code 2."""

from __future__ import annotations

import io
import subprocess
import sys
import time
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from kinematics.dataset import read_dataset, write_dataset
from kinematics.description import load_description
from kinematics.errors import ConfigError
from stream.config import config_from_dict
from stream.daemon import Daemon
from stream.log import JsonLogger
from stream.sources.config import DatasetSourceConfig
from stream.sources.dataset import (
    dataset_samples,
    dataset_source,
    in_base_frame,
    streaming_config,
)
from stream.window import Joiner, WindowConfig
from tests.stream.sources.conftest import CELL, ROBOT

pytestmark = pytest.mark.integration


def joined(ds, cfg: DatasetSourceConfig) -> list:
    """The window's points of the stream; each stream numbered 0, 1, ... with its time strictly
    increasing (the window counts a gap in the numbering as samples missed)."""
    joiner = Joiner(WindowConfig(n_joints=ds.n_joints))
    points, last = [], {}
    for s in dataset_samples(ds, streaming_config(cfg, ds)):
        seq, t = last.get(type(s), (-1, -np.inf))
        assert s.seq == seq + 1 and s.t > t, (s, seq, t)
        last[type(s)] = (s.seq, s.t)
        points += joiner.push(s)
    assert dict(joiner.counter.dropped) == {}
    return points + joiner.flush()


@pytest.mark.parametrize(
    "timing",
    [
        {"joint_rate_hz": 125.0},  # recorded time
        {"period_s": 0.77, "joint_rate_hz": 33.0, "temperature_rate_hz": 0.3},  # re-timed
        {"period_s": 1.0, "joint_rate_hz": 20.0, "temperature_rate_hz": 2.0},  # grids hit t_k
    ],
)
def test_the_stream_joins_back_to_the_datasets_points(dataset_file, timing):
    ds = in_base_frame(read_dataset(dataset_file))
    points = joined(ds, DatasetSourceConfig(path=str(dataset_file), **timing))
    assert len(points) == len(ds)
    np.testing.assert_array_equal([p.q for p in points], ds.q())
    qs = ds.table[[f"qs{i}" for i in range(1, 7)]].to_numpy()
    np.testing.assert_array_equal([p.qs for p in points], qs)
    cols = [c for c in ds.table if c.startswith("temp_")]
    np.testing.assert_array_equal([p.temperatures for p in points], ds.table[cols].to_numpy())
    assert points[0].temperature_names == tuple(c[5:] for c in cols)
    xyz = ds.table[["x", "y", "z"]].to_numpy()
    np.testing.assert_array_equal([p.xyz for p in points], xyz)
    assert {p.frame for p in points} == {"base"}


def test_tracker_poses_move_to_the_base_frame(dataset_file):
    raw = read_dataset(dataset_file)
    assert raw.meta.frame == "tracker"
    moved = in_base_frame(raw)
    assert moved.meta.frame == "base"
    np.testing.assert_allclose(moved.measured_poses(), raw.measured_poses_base(), atol=1e-12)


def test_times_it_cannot_use_need_a_period(dataset_file):
    ds = read_dataset(dataset_file)
    ds.table.loc[5, "t"] = ds.table.loc[3, "t"]  # time goes back, as in Series A's export
    with pytest.raises(ConfigError, match="set period_s"):
        streaming_config(DatasetSourceConfig(path="a.parquet"), ds)
    no_time = type(ds)(ds.table.drop(columns="t"), ds.meta)
    with pytest.raises(ConfigError, match="no time column t; set period_s"):
        streaming_config(DatasetSourceConfig(path="a.parquet"), no_time)
    streaming_config(DatasetSourceConfig(path="a.parquet", period_s=1.0), no_time)


def daemon_config(path: Path, **source) -> dict:
    return {
        "cell": CELL,
        "bus": {"mode": "peer", "multicast_scouting": False},
        "robot": [{"name": ROBOT, "description": ROBOT, "stages": ["window"]}],
        "window": {"batch_size": 10},
        "sources": [{"kind": "dataset", "path": str(path), "speed": 0, **source}],
    }


def test_the_daemon_streams_a_configured_dataset(dataset_file):
    cfg = config_from_dict(daemon_config(dataset_file, joint_rate_hz=25.0))
    log = io.StringIO()
    daemon = Daemon(cfg, logger=JsonLogger(stream=log)).start()
    try:
        window = daemon.windows[ROBOT]
        source = daemon.sources[0].source
        deadline = time.monotonic() + 60
        while (daemon.sources[0]._thread.is_alive() or window.received < source.published) and (
            time.monotonic() < deadline
        ):
            time.sleep(0.05)
        window.drain(30)
        assert daemon.failed_stage() is None
    finally:
        daemon.stop(timeout_s=30)
    assert window.points == 30  # the partial batch is flushed at stop
    assert window.received == source.published > 0
    assert "source_finished" in log.getvalue()


def test_robocal_run_refuses_a_bad_source_in_one_line(tmp_path):
    bad = tmp_path / "bad.toml"
    bad.write_text(
        f'cell = "{CELL}"\n[[robot]]\nname = "{ROBOT}"\ndescription = "{ROBOT}"\n'
        '[[sources]]\nkind = "opcua"\nurl = "http://plc:4840"\nnodes = {ambient = "ns=2;i=2"}\n'
    )
    missing = tmp_path / "missing.toml"
    missing.write_text(
        f'cell = "{CELL}"\n[bus]\nmulticast_scouting = false\n[[robot]]\nname = "{ROBOT}"\n'
        f'description = "{ROBOT}"\nstages = ["window"]\n'
        f'[[sources]]\nkind = "dataset"\npath = "{tmp_path}/nowhere.parquet"\n'
    )
    robocal = str(Path(sys.executable).with_name("robocal"))
    cases = (
        (bad, [], "url must look like opc.tcp://"),
        (missing, [], "nowhere.parquet"),
        (missing, ["--speed", "-1"], "speed must be >= 0"),
    )
    for path, extra, reason in cases:
        proc = subprocess.run(
            [robocal, "run", "--config", str(path), *extra],
            capture_output=True,
            text=True,
            timeout=120,
        )
        assert proc.returncode == 2, proc.stderr
        lines = [x for x in proc.stderr.splitlines() if not x.startswith("{")]
        assert len(lines) == 1 and reason in lines[0], proc.stderr


def test_a_retimed_dataset_keeps_its_rows(dataset_file):
    ds = read_dataset(dataset_file)
    cfg = replace(DatasetSourceConfig(path=str(dataset_file)), period_s=2.0)
    points = joined(in_base_frame(ds), cfg)
    assert [p.t for p in points] == pytest.approx(1.0 + 0.5 + 2.0 * np.arange(len(ds)))


def test_a_dataset_measured_with_another_probe_is_refused(dataset_file, tmp_path, bus):
    ds = read_dataset(dataset_file)
    tool = np.asarray(ds.meta.T_6_S)
    tool[2, 3] += 0.093  # a probe 93 mm further out than the description's tool
    path = write_dataset(
        type(ds)(ds.table, replace(ds.meta, T_6_S=tool.tolist())), tmp_path / "p.parquet"
    )
    with pytest.raises(
        ConfigError, match=r"p.parquet: its probe T_6_S .* is not the tool of robot"
    ):
        dataset_source(
            bus[0], CELL, ROBOT, DatasetSourceConfig(path=str(path)), load_description(ROBOT)
        )
