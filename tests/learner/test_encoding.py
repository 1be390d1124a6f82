"""The kinematic input encoding: pose features from the real model, wrapping angles, subsets."""

import numpy as np
import pytest

from kinematics.description import load_description
from kinematics.errors import ConfigError
from kinematics.model import RobotModel
from kinematics.transforms import pose_error
from learner.encoding import input_encoder, n_inputs, reach_m
from learner.features import FeatureSpec, feature_spec

TOOL = np.array([[1, 0, 0, 0.05], [0, 1, 0, 0.0], [0, 0, 1, 0.35], [0, 0, 0, 1.0]])
FANUC = load_description("fanuc_m900ib700").with_tool(TOOL)


def _raw(desc, n, n_temps, seed=0, dtheta_rad=2e-4):
    rng = np.random.default_rng(seed)
    q = rng.uniform(desc.limits_rad[:, 0], desc.limits_rad[:, 1], (n, desc.n_joints))
    dtheta = rng.normal(0.0, dtheta_rad, (n, desc.n_joints))
    temps = rng.uniform(15, 60, (n, n_temps))
    return np.hstack([q, dtheta, temps])


def test_pose_and_deflection_inputs_come_from_the_nominal_model():
    spec = feature_spec(FANUC, n_temperatures=2, has_secondary=True)
    X = _raw(FANUC, 50, 2)
    Z = input_encoder(spec, "kinematic")(X)
    assert Z.shape == (50, n_inputs(spec, "kinematic")) == (50, 2 * 6 + 12 + 6 + 2)
    model = RobotModel(FANUC)
    q, dtheta = X[:, :6], X[:, 6:12]
    T = model.fk(q)
    reach, d_max = reach_m(FANUC), FANUC.sensors.deflection_max_rad
    np.testing.assert_allclose(Z[:, 12:15] * reach, T[:, :3, 3], atol=1e-12)
    np.testing.assert_allclose(Z[:, 15:24], T[:, :3, :3].reshape(-1, 9), atol=1e-12)
    # J(q) dtheta is the first-order pose change of really deflecting the joints.
    moved = pose_error(model.fk(q + dtheta), T)
    scale = np.repeat([reach * d_max, d_max], 3)
    np.testing.assert_allclose(Z[:, 24:30] * scale, moved, atol=2e-6)  # 2nd order
    np.testing.assert_allclose(Z[:, 30:], spec.scale(X)[:, 12:], atol=0)
    assert np.abs(Z).max() <= 1.0 + 1e-9


def test_a_full_turn_of_a_wrist_joint_changes_no_input():
    spec = feature_spec(FANUC, n_temperatures=0, has_secondary=False)
    X = _raw(FANUC, 20, 0)[:, :6]
    X[:, 3] = np.clip(X[:, 3], -np.pi, np.pi)
    turned = X.copy()
    turned[:, 3] += 2 * np.pi
    np.testing.assert_allclose(
        input_encoder(spec, "kinematic")(turned), input_encoder(spec, "kinematic")(X), atol=1e-12
    )
    assert not np.allclose(spec.scale(turned), spec.scale(X))


@pytest.mark.parametrize(
    ("secondary", "temps", "expected"), [(True, 3, 33), (False, 3, 27), (False, 0, 24)]
)
def test_feature_subsets_encode_to_the_announced_width(secondary, temps, expected):
    spec = feature_spec(FANUC, n_temperatures=temps, has_secondary=secondary)
    X = _raw(FANUC, 7, temps)
    X = X if secondary else np.hstack([X[:, :6], X[:, 12:]])
    assert (
        input_encoder(spec, "kinematic")(X).shape
        == (7, expected)
        == (7, n_inputs(spec, "kinematic"))
    )
    assert n_inputs(spec, "minmax") == spec.n_features


def test_specs_the_encoding_cannot_read_are_refused():
    bare = FeatureSpec(names=("q1", "q2"), low=np.array([-1.0, -1.0]), high=np.array([1.0, 1.0]))
    with pytest.raises(ConfigError, match="needs the robot description"):
        n_inputs(bare, "kinematic")
    with pytest.raises(ConfigError, match="encoding must be one of"):
        n_inputs(bare, "fourier")
    spec = feature_spec(FANUC, n_temperatures=1, has_secondary=False)
    shuffled = FeatureSpec(
        names=spec.names[::-1], low=spec.low[::-1], high=spec.high[::-1], description=FANUC
    )
    with pytest.raises(ConfigError, match="features .* first"):
        input_encoder(shuffled, "kinematic")
