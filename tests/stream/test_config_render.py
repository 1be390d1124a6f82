"""Daemon configs written from Python read back as the daemon reads them."""

import pytest

from kinematics.errors import ConfigError
from stream.bus import BusConfig
from stream.config import load_config
from stream.config_render import loopback_config, write_config


def test_a_written_config_loads_back_with_its_tables(tmp_path):
    robot = {"name": "r1", "description": "ur10", "stages": ["window", "learner"]}
    raw = loopback_config(
        "c1",
        7455,
        robot,
        shutdown_timeout_s=5.0,
        learner={"holdout_every": 4, "continual": {"memory": 40}},
        recorder={"path": str(tmp_path / "c1.mcap")},
    )
    cfg = load_config(write_config(tmp_path / "robocal.toml", raw))
    assert cfg.bus == BusConfig.loopback(7455, listen=True)
    assert (cfg.cell, cfg.robots[0].stages, cfg.shutdown_timeout_s) == (
        "c1",
        ("window", "learner"),
        5.0,
    )
    assert (cfg.learner.holdout_every, cfg.learner.continual.memory) == (4, 40)
    assert cfg.recorder.path == str(tmp_path / "c1.mcap")


def test_a_config_the_daemon_would_refuse_is_not_written(tmp_path):
    raw = loopback_config("c1", 7455, {"name": "r1", "description": "ur10", "stages": ["nope"]})
    with pytest.raises(ConfigError, match="unknown stage"):
        write_config(tmp_path / "robocal.toml", raw)
    assert not (tmp_path / "robocal.toml").exists()
