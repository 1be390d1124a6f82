"""Robot descriptions: malformed TOML gives one-line errors; TOML round trip."""

import numpy as np
import pytest

from kinematics.description import description_to_toml, load_description
from kinematics.errors import DescriptionError

GOOD_JOINT = """
[[joint]]
a_m = 0.1
d_m = 0.2
alpha_deg = 90.0
lower_deg = -170.0
upper_deg = 170.0
"""
HEAD = 'name = "r"\n'


def write(tmp_path, text: str):
    path = tmp_path / "robot.toml"
    path.write_text(text)
    return path


@pytest.mark.parametrize(
    "text, match",
    [
        (HEAD + GOOD_JOINT.replace("a_m = 0.1\n", ""), r"joint 1: missing field\(s\) a_m"),
        ('name = "r"\n' + GOOD_JOINT + GOOD_JOINT.replace("d_m", "dd_m"), "joint 2: missing"),
        ('name = "r"\n' + GOOD_JOINT + "colour = 1\n", r"joint 1: unknown field\(s\) colour"),
        (
            'name = "r"\n' + GOOD_JOINT.replace("lower_deg = -170.0", "lower_deg = 170.0"),
            "joint 1: joint limits must satisfy lower_deg < upper_deg, got 170.0 >= 170.0",
        ),
        ('name = "r"\n' + GOOD_JOINT.replace("d_m = 0.2", "d_m = nan"), "joint 1: joint.d_m must"),
        (
            'name = "r"\n' + GOOD_JOINT.replace("upper_deg = 170.0", "upper_deg = nan"),
            "joint 1: joint limits must satisfy lower_deg < upper_deg",
        ),
        (
            'name = "r"\ncoupling = "j4_plus_j3"\n' + GOOD_JOINT,
            "coupling must be one of .*got 'j4_plus_j3'",
        ),
        (
            'name = "r"\ncoupling = "j3_plus_j2"\n' + GOOD_JOINT * 2,
            "coupling 'j3_plus_j2' needs at least 3 joints",
        ),
        ('name = "r"\nconvention = "mdh"\n' + GOOD_JOINT, "convention must be 'dh_hayati'"),
        (GOOD_JOINT, "missing field 'name'"),
        ('name = "r"\n', r"missing \[\[joint\]\] tables"),
        ('name = "r"\n' + GOOD_JOINT + "com_m = [0.0, 1.0]\n", "joint 1: com_m must have 3"),
        ('name = "r"\n' + GOOD_JOINT + "mass_kg = -1.0\n", "joint 1: joint.mass_kg must be >= 0"),
        ('name = "r\n', "invalid TOML"),
        (
            'name = "r"\n' + GOOD_JOINT + "[sensors]\ntemperature_min_c = 50.0\n"
            "temperature_max_c = 10.0\n",
            "sensors.temperature_min_c must be < temperature_max_c",
        ),
    ],
)
def test_malformed_toml_is_one_line(tmp_path, text, match):
    with pytest.raises(DescriptionError, match=match) as info:
        load_description(write(tmp_path, text))
    message = str(info.value)
    assert "\n" not in message and message.startswith(str(tmp_path / "robot.toml"))


def test_unknown_robot_and_missing_path(tmp_path):
    with pytest.raises(DescriptionError, match="unknown robot 'kuka'; shipped: fanuc"):
        load_description("kuka")
    with pytest.raises(DescriptionError, match="robot description not found"):
        load_description(tmp_path / "none.toml")


@pytest.mark.parametrize("robot", ["ur10", "fanuc_m900ib700"])
def test_toml_round_trip(tmp_path, robot):
    desc = load_description(robot)
    tool = np.array([[0.0, -1.0, 0.0, 0.01], [1.0, 0.0, 0.0, -0.02], [0, 0, 1, 0.3], [0, 0, 0, 1]])
    desc = desc.with_tool(tool)
    back = load_description(write(tmp_path, description_to_toml(desc)))
    assert back.name == desc.name and back.coupling == desc.coupling
    assert back.joints == desc.joints and back.sensors == desc.sensors
    np.testing.assert_allclose(back.tool, desc.tool, atol=1e-15)


def test_limits_and_coupling():
    fanuc = load_description("fanuc_m900ib700")
    np.testing.assert_allclose(np.rad2deg(fanuc.limits_rad[1]), [-64.0, 90.0])
    q = np.array([[0.1, 0.2, 0.3, 0.0, 0.0, 0.0]])
    np.testing.assert_allclose(fanuc.to_dh(q)[0, :3], [0.1, 0.2, 0.5])
    np.testing.assert_allclose(load_description("ur10").to_dh(q), q)
