"""Geometric calibration: identifiable parameters, recovery on synthetic data, bad input."""

from dataclasses import replace

import numpy as np
import pandas as pd
import pytest

from kinematics.calibration import (
    CalibrationConfig,
    GeometricFrames,
    calibrate,
    calibration_parameter_names,
    identifiable,
    prior_std,
)
from kinematics.dataset import Dataset, DatasetMeta
from kinematics.description import description_to_toml, load_description
from kinematics.effects import EFFECTS
from kinematics.errors import ConfigError, DatasetError, IdentifiabilityError
from kinematics.identification.conditions import observations_from_dataset
from kinematics.identification.fitting import jacobian, residual_matrix
from kinematics.model import RobotModel
from kinematics.transforms import transform_from_xyz_rpy, xyz_quat_from_transform

NOISE_M = 10e-6


def perturbed(desc, rng, length_m=5e-4, angle_deg=0.03):
    """``desc`` with random DH deviations (the geometric effect emulated in the table)."""
    joints = tuple(
        replace(
            j,
            a_m=j.a_m + rng.normal(0, length_m),
            d_m=j.d_m + rng.normal(0, length_m),
            alpha_deg=j.alpha_deg + rng.normal(0, angle_deg),
            beta_deg=j.beta_deg + rng.normal(0, angle_deg),
            offset_deg=j.offset_deg + rng.normal(0, angle_deg),
        )
        for j in desc.joints
    )
    return replace(desc, joints=joints)


def measured(desc_true, q, T_W_0, rng, noise_m=NOISE_M, robot=None):
    T = T_W_0[None] @ RobotModel(desc_true).fk(q)
    T[:, :3, 3] += rng.normal(0, noise_m, (len(q), 3))
    xyz, quat = xyz_quat_from_transform(T)
    cols = [
        "t",
        *(f"q{i}" for i in range(1, q.shape[1] + 1)),
        "x",
        "y",
        "z",
        "qx",
        "qy",
        "qz",
        "qw",
    ]
    table = pd.DataFrame(np.c_[np.arange(len(q)), q, xyz, quat], columns=cols)
    meta = DatasetMeta(robot=robot or desc_true.name, frame="tracker", T_W_0=T_W_0.tolist())
    return Dataset(table, meta)


def joints(desc, n, rng):
    lim = np.clip(desc.limits_rad, -np.pi, np.pi)
    return rng.uniform(lim[:, 0], lim[:, 1], (n, desc.n_joints))


@pytest.fixture(scope="module")
def ur10_case():
    rng = np.random.default_rng(7)
    desc = load_description("ur10")
    truth = perturbed(desc, rng)
    T_W_0 = transform_from_xyz_rpy([2.0, -0.5, 0.2], [0.0, 0.0, 2.0])
    ds = measured(truth, joints(desc, 250, rng), T_W_0, rng)
    return desc, truth, T_W_0, ds, calibrate(desc, ds)


def test_parameter_names_cover_dh_and_frames():
    names = calibration_parameter_names(load_description("fanuc_m900ib700"))
    assert len(names) == 42 and names[:5] == (
        "a1_m",
        "d1_m",
        "alpha1_rad",
        "beta1_rad",
        "offset1_rad",
    )
    assert names[30:33] == ("base_x_m", "base_y_m", "base_z_m")


def test_identifiable_drops_dependent_columns():
    rng = np.random.default_rng(0)
    A = rng.normal(size=(50, 3))
    J = np.c_[A, A[:, 0] - 2 * A[:, 1], np.zeros(50)]
    ident = identifiable(J, ("a", "b", "c", "d", "e"), 1e-6)
    assert len(ident.kept) == 3 and "e" in ident.dropped
    assert len({"a", "b", "d"} & set(ident.dropped)) == 1
    assert ident.condition_number < 1e3


def test_analytic_jacobian_matches_finite_differences():
    rng = np.random.default_rng(3)
    desc = load_description("fanuc_m900ib700")
    T_W_0 = transform_from_xyz_rpy([3.0, 1.0, 0.2], [0.1, -0.05, 2.8])
    ds = measured(desc, joints(desc, 30, rng), T_W_0, rng, noise_m=1e-3)
    model, obs = RobotModel(desc), observations_from_dataset(ds, desc)
    effect = GeometricFrames(desc)
    p = rng.normal(0, 1e-2, 42)
    J = jacobian(model, obs, [(effect, p)], 0.5)
    for j in (0, 8, 14, 29, 33, 40):
        h = np.zeros(42)
        h[j] = 1e-7
        plus, minus = (residual_matrix(model, obs, [(effect, p + s * h)]) for s in (1, -1))
        fd = (plus - minus) / 2e-7
        fd[:, 3:] *= 0.5
        assert np.allclose(J[:, j], fd.ravel(), atol=1e-6 * np.abs(fd).max())


def test_calibration_recovers_the_true_robot(ur10_case):
    desc, truth, T_W_0, ds, result = ur10_case
    ident = result.identifiability
    # Known dependencies: d1 with the base z, d2/d3/d4 along parallel axes, tool rz with offset6.
    assert len(ident.kept) == 30 and len(ident.dropped) == 12
    assert len({"d1_m", "base_z_m"} & set(ident.dropped)) == 1
    assert np.isfinite(ident.condition_number) and ident.condition_number < 1e3
    assert result.residual.mean_mm < 2.5 * NOISE_M * 1e3 * 1.6
    rng = np.random.default_rng(99)
    q = joints(desc, 200, rng)
    T_cal = result.T_W_0[None] @ RobotModel(result.description).fk(q)
    T_true = T_W_0[None] @ RobotModel(truth).fk(q)
    uncal = np.linalg.norm((T_W_0[None] @ RobotModel(desc).fk(q) - T_true)[:, :3, 3], axis=1)
    err = np.linalg.norm(T_cal[:, :3, 3] - T_true[:, :3, 3], axis=1)
    assert err.mean() < 0.02 * uncal.mean() and err.max() < 5 * NOISE_M * 3
    assert all(s > 0 for s in result.std.values())


def test_calibrated_description_round_trips_through_toml(ur10_case, tmp_path):
    *_, result = ur10_case
    path = tmp_path / "calibrated.toml"
    path.write_text(description_to_toml(result.description))
    q = np.zeros((1, 6))
    back = RobotModel(load_description(path)).fk(q)
    assert np.allclose(back, RobotModel(result.description).fk(q), atol=1e-12)


def test_unexcited_tool_rotation_is_dropped_not_guessed(ur10_case):
    # The tool z rotation and offset6 turn about the same axis: one of them is dropped.
    *_, result = ur10_case
    assert len({"offset6_rad", "tool_rz_rad"} & set(result.identifiability.dropped)) == 1


def test_a_joint_that_never_moves_raises():
    rng = np.random.default_rng(1)
    desc = load_description("ur10")
    q = joints(desc, 120, rng)
    q[:, 1] = 0.3
    ds = measured(desc, q, np.eye(4), rng)
    with pytest.raises(IdentifiabilityError, match="joint 2 moves over 0 deg"):
        calibrate(desc, ds)


def test_too_few_points_raise_identifiability_error():
    rng = np.random.default_rng(2)
    desc = load_description("ur10")
    ds = measured(desc, joints(desc, 12, rng), np.eye(4), rng)
    with pytest.raises(IdentifiabilityError, match="at least 30 points"):
        calibrate(desc, ds, CalibrationConfig(min_points_per_parameter=1.0))


def test_robot_mismatch_raises_dataset_error():
    rng = np.random.default_rng(2)
    desc = load_description("ur10")
    ds = measured(desc, joints(desc, 40, rng), np.eye(4), rng)
    with pytest.raises(DatasetError, match="robot 'ur10', description is 'fanuc_m900ib700'"):
        calibrate(load_description("fanuc_m900ib700"), ds)
    five = Dataset(ds.table.drop(columns=["q6"]), ds.meta)
    with pytest.raises(DatasetError, match="5 joint columns"):
        calibrate(desc, five)


def test_config_is_validated():
    with pytest.raises(ConfigError, match="rank_rtol"):
        CalibrationConfig(rank_rtol=2.0)
    with pytest.raises(ConfigError, match="prior_mm must be > 0"):
        CalibrationConfig(prior_mm=0.0)


def test_the_prior_holds_deviations_and_leaves_frames_free():
    """One standard deviation of each DH deviation moves the tool by ``prior_mm`` over the
    joint limits; frames, and effects that need conditions rest lacks, are free."""
    desc = load_description("ur10")
    model = RobotModel(desc)
    std = prior_std(model, GeometricFrames(desc), 0.3)
    assert np.all(np.isfinite(std[:30])) and np.all(np.isinf(std[30:]))
    assert 1e-4 < std[0] < 1e-3  # a1: a length moves the tool by about itself
    for name in ("base_frame", "thermal_expansion", "backlash"):
        assert np.all(np.isinf(prior_std(model, EFFECTS[name](), 0.3))), name
    assert np.all(np.isfinite(prior_std(model, EFFECTS["gear_periodic"](), 0.3)))


def test_the_prior_leaves_spread_poses_and_holds_one_region_elsewhere(ur10_case):
    """Spread poses calibrate the same with the prior or without. Poses along one path, with a
    gear error the geometry lacks, fit deviations that cancel there; the prior holds them."""
    desc, truth, T_W_0, ds, result = ur10_case
    rng = np.random.default_rng(99)
    q = joints(desc, 200, rng)
    free = calibrate(desc, ds, CalibrationConfig(prior_mm=None))
    T_prior = result.T_W_0[None] @ RobotModel(result.description).fk(q)
    T_free = free.T_W_0[None] @ RobotModel(free.description).fk(q)
    assert np.abs(T_prior[:, :3, 3] - T_free[:, :3, 3]).max() < 2e-6
    rng = np.random.default_rng(1)
    truth = perturbed(desc, rng)
    path = joints(desc, 1, rng) + rng.uniform(-0.4, 0.4, (150, 1)) * rng.normal(0, 1, 6)
    q_path = path + rng.uniform(-0.03, 0.03, (150, 6))

    def geared(q):
        return q + 3e-4 * np.sin(3 * q)  # what the encoders miss: 0.3 mrad at order 3

    one_region = measured(truth, geared(q_path), T_W_0, rng, noise_m=20e-6)
    one_region.table[[f"q{i}" for i in range(1, 7)]] = q_path
    T_true = T_W_0[None] @ RobotModel(truth).fk(geared(q))
    errors = []
    for config in (CalibrationConfig(prior_mm=None), CalibrationConfig()):
        r = calibrate(desc, one_region, config)
        T = r.T_W_0[None] @ RobotModel(r.description).fk(q)
        errors.append(np.linalg.norm(T[:, :3, 3] - T_true[:, :3, 3], axis=1).mean())
    assert r.identifiability.condition_number > 300
    assert errors[1] < 0.75 * errors[0], errors  # measured 1.88 -> 1.24 mm (condition 420)
