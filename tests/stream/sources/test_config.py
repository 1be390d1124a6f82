"""``[[sources]]`` in the daemon TOML: the example's (commented) tables load, and each bad
setting is one ConfigError line naming it."""

from __future__ import annotations

import tomllib
from pathlib import Path

import pytest

from kinematics.errors import ConfigError
from stream.config import config_from_dict, load_config
from stream.sources.config import OpcUaSourceConfig, Ros2SourceConfig

EXAMPLE = Path(__file__).resolve().parents[3] / "deploy" / "robocal.example.toml"
ROBOT = [{"name": "r1", "description": "ur10"}]


def example_sources() -> list[dict]:
    """The example's commented ``[[sources]]`` tables, uncommented."""
    lines = EXAMPLE.read_text().splitlines()
    first = lines.index("# [[sources]]")
    block = []
    for line in lines[first:]:
        if not line.startswith("# "):
            break
        block.append(line[2:])
    return tomllib.loads("\n".join(block))["sources"]


def test_the_examples_source_tables_load():
    raw = tomllib.loads(EXAMPLE.read_text())
    tables = example_sources()
    assert [t["kind"] for t in tables] == ["ros2", "opcua", "dataset"]
    cfg = config_from_dict({**raw, "sources": tables})
    assert [type(s).__name__ for s in cfg.sources] == [
        "Ros2SourceConfig",
        "OpcUaSourceConfig",
        "DatasetSourceConfig",
    ]
    assert isinstance(cfg.sources[1], OpcUaSourceConfig)
    assert dict(cfg.sources[1].nodes) == {
        "base": "ns=2;s=Cell.Base",
        "j1_gear": "ns=2;s=Cell.J1Gear",
    }
    assert isinstance(cfg.sources[0], Ros2SourceConfig) and len(cfg.sources[0].joint_names) == 6


@pytest.mark.parametrize(
    ("table", "message"),
    [
        ({"kind": "modbus"}, "kind must be one of ['dataset', 'opcua', 'ros2', 'sim']"),
        ({"url": "opc.tcp://plc:4840"}, "kind must be one of"),
        ({"kind": "opcua", "url": "http://plc", "nodes": {"a": "ns=2;i=1"}}, "url must look like"),
        ({"kind": "opcua", "url": "opc.tcp://plc:4840"}, "nodes must map temperature channels"),
        ({"kind": "opcua", "url": "opc.tcp://p", "nodes": {"a": "x"}, "period_s": 0}, "period_s"),
        ({"kind": "ros2"}, "joint_names must list the ROS joint names"),
        ({"kind": "ros2", "joint_names": ["a"], "pose_type": "Odometry"}, "pose_type must be"),
        ({"kind": "ros2", "joint_names": ["a"], "frame": "world"}, "frame must be one of"),
        ({"kind": "ros2", "joint_names": ["a"], "connect": ["localhost"]}, "connect must list"),
        ({"kind": "ros2", "joint_names": ["a"], "joint_topic": "/*"}, "joint_topic must be"),
        ({"kind": "dataset"}, "path must name a dataset file"),
        ({"kind": "dataset", "path": "a.parquet", "speed": -1}, "speed must be >= 0"),
        ({"kind": "dataset", "path": "a.parquet", "joint_rate_hz": 0}, "joint_rate_hz must be"),
        ({"kind": "dataset", "path": "a.parquet", "robot": "r2"}, "robot 'r2' is not one of"),
        ({"kind": "sim", "n": 0}, "n must be an int >= 1"),
        ({"kind": "sim", "colour": "red"}, "unknown field(s) ['colour']"),
    ],
)
def test_bad_source_settings_are_one_line(table, message):
    with pytest.raises(ConfigError) as err:
        config_from_dict({"robot": ROBOT, "sources": [table]})
    assert message in str(err.value) and "\n" not in str(err.value)


def test_a_source_needs_its_robot_named_when_there_are_several(tmp_path):
    path = tmp_path / "two.toml"
    path.write_text(
        '[[robot]]\nname = "a"\ndescription = "ur10"\n[[robot]]\nname = "b"\ndescription = "ur10"\n'
        '[[sources]]\nkind = "sim"\nscenario = "paper"\n'
    )
    with pytest.raises(ConfigError, match=r"two.toml: .*robot '' is not one of \['a', 'b'\]"):
        load_config(path)
