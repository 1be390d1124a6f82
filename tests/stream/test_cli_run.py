"""``robocal demo`` / ``robocal run``: a short demo run end to end, and bad input exits 2."""

import json

import numpy as np
import pytest
import torch

from kinematics.errors import ConfigError
from learner.config import ContinualConfig, ModelConfig, TrainConfig
from learner.snapshot import save_snapshot
from stream.bus import free_port
from stream.cli import main
from stream.config import load_config
from stream.config_render import loopback_config, write_config
from stream.daemon import Daemon
from stream.dashboard import read_scalars
from stream.demo import run_demo
from stream.learner_core import LearnerStageConfig
from stream.mcap_io import read_mcap

SMALL = LearnerStageConfig(
    model=ModelConfig(hidden_layers=1, neurons=24),
    train=TrainConfig(batch_size=16),
    continual=ContinualConfig(memory=60, batch=30, init=30, epochs_per_update=8, init_epochs=60),
)


@pytest.mark.integration
def test_short_demo_writes_rrd_and_mcap_and_learns(tmp_path):
    torch.set_num_threads(1)
    result = run_demo(tmp_path, n=120, seed=0, learner=SMALL, period_s=1.0)
    assert result.model_version >= 3 and result.n_test == 12 and result.dropped == {}
    assert result.learned["mean_mm"] < result.uncalibrated_mean_mm
    comp = result.compensation
    assert comp["n"] == 12 and comp["after_mean_mm"] < comp["before_mean_mm"]
    assert 1 <= comp["reached"] <= 12 and comp["reached_after_mean_mm"] <= comp["after_mean_mm"]
    series = read_scalars(result.rrd)
    versions, test_mean = (
        series["/metrics/model/version"][1][:, 0],
        series["/metrics/test_error/mean"][1],
    )
    assert list(versions) == list(range(1, result.model_version + 1))
    assert np.isclose(test_mean[-1, 0], result.learned["mean_mm"])
    for name in ("epistemic", "aleatoric"):
        assert len(series[f"/metrics/uncertainty/{name}"][1]) == result.model_version
    assert len(series["/points/left/error"][1]) == result.n_points
    keys = {r.key.rsplit("/", 1)[1] for r in read_mcap(result.mcap)}
    assert {"joints", "tracker", "temperature", "points", "batches", "model", "metrics"} <= keys
    log = [json.loads(x) for x in (tmp_path / "robocal.log.jsonl").read_text().splitlines()]
    assert log[0]["event"] == "daemon_started" and log[-1]["event"] == "daemon_stopped"


@pytest.mark.parametrize(
    "argv",
    [
        ["demo", "--n", "10", "--out", "{tmp}"],
        ["run", "--config", "{tmp}/missing.toml"],
        ["replay", "{tmp}/missing.mcap"],
        ["replay", "{tmp}/x.mcap", "--speed", "0"],
    ],
)
def test_bad_input_exits_2_with_one_line(argv, tmp_path, capsys):
    assert main([a.format(tmp=tmp_path) for a in argv]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) >= 1 and err[-1].startswith("robocal: error:")


def test_a_start_from_model_reading_a_thermometer_the_window_does_not_pin_stops_the_start(
    train_fanuc, tmp_path
):
    """Every batch would be refused as ``features``: the daemon says so before it starts
    (``robocal run`` prints the ConfigError as its one line and exits 2)."""
    _, model, _ = train_fanuc(40, ModelConfig(hidden_layers=1, neurons=8), 2, lambda q: 0 * q)
    save_snapshot(model, tmp_path / "day1.safetensors")
    robot = {"name": "arm", "description": "fanuc_m900ib700", "stages": ["window", "learner"]}

    def config(names: list[str]) -> str:
        raw = loopback_config(
            "plant",
            free_port(),
            robot,
            window={"temperature_names": names},
            learner={"start_from": str(tmp_path / "day1.safetensors")},
        )
        return str(write_config(tmp_path / "robocal.toml", raw))

    with pytest.raises(ConfigError) as refused:
        Daemon(load_config(config(["cabinet"]))).start()
    assert str(refused.value) == (
        f"learner.start_from {tmp_path / 'day1.safetensors'}: its model reads temp_ambient, "
        "which window.temperature_names (cabinet) does not give"
    )
    daemon = Daemon(load_config(config(["ambient"]))).start()  # the thermometer it reads
    assert daemon.stop(timeout_s=10.0) == {}
