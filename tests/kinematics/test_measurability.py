"""Tracker visibility: incidence angle and distance thresholds, vectorised."""

import numpy as np
import pytest

from kinematics.description import load_description
from kinematics.errors import ConfigError
from kinematics.measurability import (
    MeasurabilityConfig,
    measurability,
    measurability_from_poses,
)
from kinematics.model import RobotModel
from kinematics.transforms import transform_from_xyz_rpy


def probe_at(distance_m: float, tilt_deg: float) -> np.ndarray:
    """A probe on the +x axis whose z axis points at the tracker, tilted about y by ``tilt``."""
    return transform_from_xyz_rpy([distance_m, 0.0, 0.0], [0.0, np.deg2rad(-90.0 + tilt_deg), 0])


@pytest.mark.parametrize(
    "distance, tilt, visible",
    [
        (2.0, 0.0, True),
        (2.0, 44.9, True),
        (2.0, 45.1, False),
        (2.0, -44.9, True),
        (1.49, 0.0, False),
        (1.51, 30.0, True),
        (3.0, 180.0, False),
    ],
)
def test_thresholds(distance, tilt, visible):
    m = measurability_from_poses(probe_at(distance, tilt)[None])
    assert m.visible.tolist() == [visible]
    assert m.angle_rad[0] == pytest.approx(np.deg2rad(abs(tilt)), abs=1e-9)
    assert m.distance_m[0] == pytest.approx(distance)


def test_custom_thresholds():
    config = MeasurabilityConfig(max_angle_deg=60.0, min_distance_m=1.0)
    assert measurability_from_poses(probe_at(1.2, 50.0)[None], config).visible.tolist() == [True]


def test_joint_configurations_match_pose_version():
    model = RobotModel(load_description("ur10"))
    q = np.random.default_rng(0).uniform(-np.pi, np.pi, (500, 6))
    T_W_0 = transform_from_xyz_rpy([2.5, -1.5, -1.2], [0.0, 0.0, -0.5])
    T_6_S = transform_from_xyz_rpy([0.0, 0.0, 0.093], [0.0, 0.0, -np.pi / 2])
    m = measurability(model, q, T_W_0, T_6_S)
    poses = T_W_0[None] @ model.fk(q, frame="flange") @ T_6_S[None]
    ref = measurability_from_poses(poses)
    np.testing.assert_array_equal(m.visible, ref.visible)
    np.testing.assert_allclose(m.angle_rad, ref.angle_rad)
    assert m.visible.shape == (500,) and 0 < m.visible.sum() < 500


@pytest.mark.parametrize(
    "kwargs, match",
    [
        ({"max_angle_deg": 0.0}, "max_angle_deg must be in"),
        ({"max_angle_deg": 200.0}, "got 200.0"),
        ({"min_distance_m": -1.0}, "min_distance_m must be >= 0, got -1.0"),
    ],
)
def test_config_validation(kwargs, match):
    with pytest.raises(ConfigError, match=match):
        MeasurabilityConfig(**kwargs)
