"""Transforms, quaternions and the pose error label of DESIGN.md."""

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from kinematics.transforms import (
    apply_error,
    invert,
    pose_error,
    rotation_angle,
    skew_to_rotation,
    transform,
    transform_from_xyz_quat,
    transform_from_xyz_rpy,
    vee_skew,
    xyz_quat_from_transform,
    xyz_rpy_from_transform,
)


def random_poses(n: int, seed: int = 0, max_angle: float = np.pi) -> np.ndarray:
    rng = np.random.default_rng(seed)
    axes = rng.normal(size=(n, 3))
    axes /= np.linalg.norm(axes, axis=1, keepdims=True)
    rot = Rotation.from_rotvec(axes * rng.uniform(0, max_angle, (n, 1))).as_matrix()
    return transform(rot, rng.normal(0, 1.0, (n, 3)))


def test_pose_error_is_zero_for_identical_poses():
    T = random_poses(50)
    np.testing.assert_array_equal(pose_error(T, T)[:, :3], 0.0)
    np.testing.assert_allclose(pose_error(T, T)[:, 3:], 0.0, atol=1e-15)


@pytest.mark.parametrize("axis", [0, 1, 2])
def test_pose_error_of_a_small_known_rotation(axis):
    angle = 1e-3
    rotvec = np.zeros(3)
    rotvec[axis] = angle
    Tc = random_poses(1, seed=axis)
    Tm = Tc.copy()
    Tm[0, :3, :3] = Rotation.from_rotvec(rotvec).as_matrix() @ Tc[0, :3, :3]
    Tm[0, :3, 3] += [1e-3, -2e-3, 0.5e-3]
    e = pose_error(Tm, Tc)[0]
    np.testing.assert_allclose(e[:3], [1e-3, -2e-3, 0.5e-3], atol=1e-15)
    expected = np.zeros(3)
    expected[axis] = np.sin(angle)  # vec(R) of a rotation by theta about u is sin(theta) u
    np.testing.assert_allclose(e[3:], expected, atol=1e-15)


def test_apply_error_inverts_pose_error():
    Tc = random_poses(200, seed=1)
    Tm = Tc.copy()
    Tm[:, :3, :3] = random_poses(200, seed=2, max_angle=1.2)[:, :3, :3] @ Tc[:, :3, :3]
    Tm[:, :3, 3] += np.random.default_rng(3).normal(0, 0.01, (200, 3))
    np.testing.assert_allclose(apply_error(Tc, pose_error(Tm, Tc)), Tm, atol=1e-12)


def test_skew_to_rotation_inverts_vee():
    R = random_poses(100, seed=4, max_angle=1.5)[:, :3, :3]
    np.testing.assert_allclose(skew_to_rotation(vee_skew(R)), R, atol=1e-12)


def test_invert_and_rotation_angle():
    T = random_poses(100, seed=5)
    np.testing.assert_allclose(T @ invert(T), np.broadcast_to(np.eye(4), T.shape), atol=1e-12)
    R = Rotation.from_rotvec([[0.0, 0.0, 0.3], [0.2, 0.0, 0.0]]).as_matrix()
    np.testing.assert_allclose(rotation_angle(R), [0.3, 0.2], atol=1e-12)


def test_quaternion_round_trip_and_sign():
    T = random_poses(100, seed=6)
    xyz, quat = xyz_quat_from_transform(T)
    assert np.all(quat[:, 3] >= 0)
    np.testing.assert_allclose(transform_from_xyz_quat(xyz, quat), T, atol=1e-12)
    np.testing.assert_allclose(transform_from_xyz_quat(xyz, -quat), T, atol=1e-12)


def test_rpy_round_trip_is_fixed_axis():
    xyz, rpy = [0.1, -0.2, 0.3], [0.3, -0.4, 1.2]
    T = transform_from_xyz_rpy(xyz, rpy)
    R = Rotation.from_rotvec([0, 0, 1.2]) * Rotation.from_rotvec([0, -0.4, 0])
    R = R * Rotation.from_rotvec([0.3, 0, 0])
    np.testing.assert_allclose(T[:3, :3], R.as_matrix(), atol=1e-15)  # Rz Ry Rx
    back_xyz, back_rpy = xyz_rpy_from_transform(T)
    np.testing.assert_allclose(back_xyz, xyz)
    np.testing.assert_allclose(back_rpy, rpy, atol=1e-12)
