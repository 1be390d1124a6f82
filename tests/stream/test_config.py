"""Daemon config: the shipped example loads; bad values fail in one line naming the file."""

from pathlib import Path

import pytest

from kinematics.errors import ConfigError
from learner.config import ContinualConfig, ModelConfig, TrainConfig
from stream.config import load_config
from stream.demo import DEMO_LEARNER

EXAMPLE = Path(__file__).resolve().parents[2] / "deploy" / "robocal.example.toml"


def test_example_config_loads():
    cfg = load_config(EXAMPLE)
    assert cfg.robots and cfg.bus.mode in ("peer", "client")
    assert cfg.learner.continual.memory >= cfg.learner.continual.batch


def test_example_learner_is_the_benchmarked_one():
    """BENCHMARKS.md measures the library defaults; the example runs them."""
    learner = load_config(EXAMPLE).learner
    assert learner.model == ModelConfig()
    assert learner.train == TrainConfig()
    assert learner.continual == ContinualConfig()
    assert learner == DEMO_LEARNER  # the main job runs what a line runs


@pytest.mark.parametrize(
    "text, match",
    [
        ("cell = 'c'\n", "at least one"),
        ("[[robot]]\nname = 'r'\ndescription = 'ur10'\nstages = ['nope']\n", "unknown stage"),
        ("[[robot]]\nname = 'r'\ndescription = 'ur10'\n[window]\nbatch_size = 0\n", "batch_size"),
        ("[[robot]]\nname = 'r'\ndescription = 'ur10'\n[window]\nsize = 3\n", "unknown field"),
        ("[[robot]]\nname = 'r'\ndescription = 'ur10'\n[bus]\nmode = 'x'\n", "bus.mode"),
        ("[[robot]]\nname = 'r'\ndescription = 'ur10'\n[learner.model]\nneurons = 0\n", "neurons"),
        ("cell = [\n", "invalid TOML"),
        (
            "[[robot]]\nname = 'r'\ndescription = 'ur10'\n[[robot]]\nname = 'r'\n"
            "description = 'ur10'\n",
            "unique",
        ),
        ("[[robot]]\nname = 'r'\ndescription = 'ur10'\nstages = ['dashboard']\n", "dashboard"),
    ],
)
def test_bad_configs_fail_in_one_line(tmp_path, text, match):
    path = tmp_path / "bad.toml"
    path.write_text(text)
    with pytest.raises(ConfigError, match=match) as info:
        load_config(path)
    assert str(path) in str(info.value) and "\n" not in str(info.value).strip()


def test_missing_file():
    with pytest.raises(ConfigError, match="not found"):
        load_config("/nonexistent/robocal.toml")


def test_two_robots_share_one_daemon_config(tmp_path):
    path = tmp_path / "two.toml"
    path.write_text(
        "[[robot]]\nname = 'a'\ndescription = 'ur10'\nstages = ['window', 'dashboard']\n"
        "[[robot]]\nname = 'b'\ndescription = 'fanuc_m900ib700'\n"
        "[dashboard]\nrrd = 'out/x.rrd'\n"
    )
    cfg = load_config(path)
    assert [r.name for r in cfg.robots] == ["a", "b"] and cfg.dashboard.rrd == "out/x.rrd"
