"""Homogeneous transforms, rotations and the pose error of DESIGN.md (pure numpy, batched).

``T_a_b`` is the pose of frame ``b`` in frame ``a``; arrays of poses are ``(N, 4, 4)``.

>>> import numpy as np
>>> T = transform_from_xyz_rpy([0.1, 0.0, 0.0], [0.0, 0.0, 0.0])
>>> pose_error(T[None], T[None]).tolist()
[[0.0, 0.0, 0.0, 0.0, 0.0, 0.0]]
"""

from __future__ import annotations

import numpy as np
from scipy.spatial.transform import Rotation

#: Arc minutes per radian: orientation errors are reported in arcmin everywhere.
ARCMIN_PER_RAD = 60.0 * 180.0 / np.pi


def transform(R: np.ndarray, p: np.ndarray) -> np.ndarray:
    """Stack rotations ``(..., 3, 3)`` and positions ``(..., 3)`` into ``(..., 4, 4)``."""
    R = np.asarray(R, dtype=float)
    p = np.asarray(p, dtype=float)
    T = np.zeros(R.shape[:-2] + (4, 4))
    T[..., :3, :3] = R
    T[..., :3, 3] = p
    T[..., 3, 3] = 1.0
    return T


def transform_from_xyz_rpy(xyz, rpy) -> np.ndarray:
    """A transform from a position (m) and fixed-axis roll-pitch-yaw (rad, ``R = Rz Ry Rx``)."""
    R = Rotation.from_euler("xyz", np.asarray(rpy, dtype=float)).as_matrix()
    return transform(R, np.asarray(xyz, dtype=float))


def xyz_rpy_from_transform(T: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Inverse of :func:`transform_from_xyz_rpy`: position (m) and roll-pitch-yaw (rad)."""
    T = np.asarray(T, dtype=float)
    return T[:3, 3].copy(), Rotation.from_matrix(T[:3, :3]).as_euler("xyz")


def transform_from_xyz_quat(xyz: np.ndarray, quat_xyzw: np.ndarray) -> np.ndarray:
    """Poses ``(N, 4, 4)`` from positions ``(N, 3)`` (m) and quaternions ``(N, 4)`` (x, y, z, w)."""
    R = Rotation.from_quat(np.atleast_2d(quat_xyzw)).as_matrix()
    return transform(R, np.atleast_2d(xyz))


def xyz_quat_from_transform(T: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Positions ``(N, 3)`` and quaternions ``(N, 4)`` (x, y, z, w, ``w >= 0``) of ``(N, 4, 4)``."""
    T = np.asarray(T, dtype=float).reshape(-1, 4, 4)
    quat = Rotation.from_matrix(T[:, :3, :3]).as_quat()
    quat *= np.where(quat[:, 3:4] < 0, -1.0, 1.0)
    return T[:, :3, 3].copy(), quat


def invert(T: np.ndarray) -> np.ndarray:
    """Inverse of rigid transforms ``(..., 4, 4)``."""
    T = np.asarray(T, dtype=float)
    Rt = np.swapaxes(T[..., :3, :3], -1, -2)
    return transform(Rt, -np.einsum("...ij,...j->...i", Rt, T[..., :3, 3]))


def vee_skew(A: np.ndarray) -> np.ndarray:
    """``vec(A) = 0.5 (A32 - A23, A13 - A31, A21 - A12)`` for ``(..., 3, 3)`` -> ``(..., 3)``."""
    return 0.5 * np.stack(
        [A[..., 2, 1] - A[..., 1, 2], A[..., 0, 2] - A[..., 2, 0], A[..., 1, 0] - A[..., 0, 1]],
        axis=-1,
    )


def pose_error(T_measured: np.ndarray, T_computed: np.ndarray) -> np.ndarray:
    """The label ``e = [p_m - p_c ; vec(R_m R_c^T)]`` (m, rad-like), ``(N, 6)``."""
    Tm = np.asarray(T_measured, dtype=float)
    Tc = np.asarray(T_computed, dtype=float)
    dp = Tm[..., :3, 3] - Tc[..., :3, 3]
    dR = np.einsum("...ij,...kj->...ik", Tm[..., :3, :3], Tc[..., :3, :3])
    return np.concatenate([dp, vee_skew(dR)], axis=-1)


def rotation_angle(R: np.ndarray) -> np.ndarray:
    """The angle (rad) of rotations ``(..., 3, 3)``."""
    tr = np.trace(R, axis1=-2, axis2=-1)
    return np.arccos(np.clip((tr - 1.0) / 2.0, -1.0, 1.0))


def apply_error(T_computed: np.ndarray, error: np.ndarray) -> np.ndarray:
    """The pose a predicted error ``(N, 6)`` moves ``T_computed`` to (inverse of pose_error)."""
    T = np.array(T_computed, dtype=float, copy=True)
    T[..., :3, 3] += error[..., :3]
    T[..., :3, :3] = np.einsum(
        "...ij,...jk->...ik", skew_to_rotation(error[..., 3:]), T[..., :3, :3]
    )
    return T


def skew_to_rotation(v: np.ndarray) -> np.ndarray:
    """The rotation whose ``vec(R)`` equals ``v`` (``|v| < 1``), axis along ``v``."""
    v = np.asarray(v, dtype=float)
    s = np.linalg.norm(v, axis=-1, keepdims=True)
    angle = np.arcsin(np.clip(s, 0.0, 1.0))
    axis = np.divide(v, s, out=np.zeros_like(v), where=s > 0)
    return (
        Rotation.from_rotvec((axis * angle).reshape(-1, 3))
        .as_matrix()
        .reshape(v.shape[:-1] + (3, 3))
    )
