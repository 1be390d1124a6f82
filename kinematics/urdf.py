"""Robot descriptions from URDF: the serial chain to a tip link, re-expressed in DH form.

pinocchio parses the URDF; at the zero configuration each revolute joint of the chain gives a
line (a point on its axis and the axis direction in the root frame). Consecutive lines give
the DH parameters by their common normal (for parallel axes the normal through the previous
frame's origin, ``d = 0``), the tip link's z axis closes the chain, and what remains between
the last DH frame and the tip link becomes the description's tool. Link masses and centres
(for gravity torques) are carried over. The result is checked against pinocchio's own FK of
the URDF; Hayati ``beta`` is never needed for an exact URDF and stays 0. Continuous joints
get limits of ±360°.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pinocchio as pin

from kinematics.description_types import JointDH, RobotDescription
from kinematics.errors import DescriptionError
from kinematics.model import RobotModel
from kinematics.transforms import invert

_REVOLUTE = ("JointModelRX", "JointModelRY", "JointModelRZ", "JointModelRevoluteUnaligned")
_CONTINUOUS = ("JointModelRUBX", "JointModelRUBY", "JointModelRUBZ")
CONTINUOUS_LIMIT_DEG = 360.0
_TOL = 1e-9


def _frame(origin: np.ndarray, x: np.ndarray, z: np.ndarray) -> np.ndarray:
    T = np.eye(4)
    T[:3, 0], T[:3, 1], T[:3, 2], T[:3, 3] = x, np.cross(z, x), z, origin
    return T


def _signed_angle(u: np.ndarray, v: np.ndarray, axis: np.ndarray) -> float:
    return float(np.arctan2(np.cross(u, v) @ axis, u @ v))


def _dh_step(
    F: np.ndarray, p: np.ndarray, w: np.ndarray, x_hint: np.ndarray, d_at_point: bool
) -> tuple[dict[str, float], np.ndarray]:
    """DH parameters from frame ``F`` (z on this joint's axis) to the line ``(p, w)``."""
    o, x_prev, z = F[:3, 3], F[:3, 0], F[:3, 2]
    r = p - o
    cross = np.cross(z, w)
    if np.linalg.norm(cross) > _TOL:  # skew or intersecting: the unique common normal
        b = z @ w
        t1 = (b * (w @ -r) - (z @ -r)) / (1.0 - b * b)
        t2 = ((w @ -r) - b * (z @ -r)) / (1.0 - b * b)
        normal = (p + t2 * w) - (o + t1 * z)
        a = float(np.linalg.norm(normal))
        x = normal / a if a > _TOL else cross / np.linalg.norm(cross)
        d = float(t1)
        a = a if a > _TOL else 0.0
    else:  # parallel: the normal through the previous origin (or through p for the tip)
        d = float(r @ z) if d_at_point else 0.0
        perp = r - (r @ z) * z
        a = float(np.linalg.norm(perp))
        if a > _TOL:
            x = perp / a
        else:
            hint = x_hint - (x_hint @ z) * z
            x = hint / np.linalg.norm(hint) if np.linalg.norm(hint) > _TOL else x_prev
            a = 0.0
    params = {
        "offset_deg": np.rad2deg(_signed_angle(x_prev, x, z)),
        "a_m": a,
        "d_m": d,
        "alpha_deg": np.rad2deg(_signed_angle(z, w, x)),
    }
    return params, _frame(o + d * z + a * x, x, w)


def _load(path: str | Path) -> pin.Model:
    path = Path(path)
    if not path.is_file():
        raise DescriptionError(f"{path}: URDF file not found")
    try:
        return pin.buildModelFromUrdf(str(path))
    except (ValueError, RuntimeError) as exc:
        raise DescriptionError(f"{path}: unreadable URDF: {str(exc).splitlines()[0]}") from None


def _chain(model: pin.Model, tip_link: str, path: Path) -> tuple[list[int], int]:
    """Joint ids from the root to ``tip_link`` (all revolute, one dof each) and its frame id."""
    if not model.existFrame(tip_link):
        raise DescriptionError(f"{path}: no link named {tip_link!r}")
    fid = model.getFrameId(tip_link)
    joints = [j for j in model.supports[model.frames[fid].parentJoint] if j > 0]
    for j in joints:
        kind = model.joints[j].shortname()
        if kind not in _REVOLUTE + _CONTINUOUS:
            raise DescriptionError(
                f"{path}: joint {model.names[j]!r} is {kind}, expected a revolute joint"
            )
    if not joints:
        raise DescriptionError(f"{path}: no joints between the root and {tip_link!r}")
    return joints, fid


def description_from_urdf(
    path: str | Path, tip_link: str | None = None, *, name: str | None = None
) -> RobotDescription:
    """The DH description of the serial chain from the URDF root to ``tip_link``.

    Joint 1's axis must be the root frame's +z axis through its origin (the DH base); the
    description's tool is ``T_n_tip``, identity when the tip link is itself a DH frame.
    Without ``tip_link`` the last link of the file is the tip.
    """
    path = Path(path)
    model = _load(path)
    if tip_link is None:
        tip_link = [f.name for f in model.frames if f.type == pin.FrameType.BODY][-1]
    joints, fid = _chain(model, tip_link, path)
    data = model.createData()
    q0 = pin.neutral(model)
    pin.computeJointJacobians(model, data, q0)
    pin.framesForwardKinematics(model, data, q0)
    lines = []
    for j in joints:
        J = pin.getJointJacobian(model, data, j, pin.ReferenceFrame.LOCAL_WORLD_ALIGNED)
        w = J[3:, model.joints[j].idx_v]
        lines.append((data.oMi[j].translation.copy(), w / np.linalg.norm(w)))
    p1, w1 = lines[0]
    if np.linalg.norm(w1 - [0, 0, 1]) > 1e-9 or np.linalg.norm(p1[:2]) > 1e-9:
        raise DescriptionError(
            f"{path}: joint 1 ({model.names[joints[0]]!r}) must turn about the root's +z axis "
            f"through its origin, got axis {np.round(w1, 6)} through {np.round(p1, 6)}"
        )
    tip = data.oMf[fid].homogeneous
    targets = [*lines[1:], (tip[:3, 3], tip[:3, 2])]
    F = np.eye(4)
    dh_joints = []
    for k, (j, (p, w)) in enumerate(zip(joints, targets, strict=True)):
        last = k == len(joints) - 1
        params, F = _dh_step(F, p, w, tip[:3, 0] if last else F[:3, 0], d_at_point=last)
        inertia = model.inertias[j]
        com_world = data.oMi[j].act(inertia.lever)
        lower, upper = _limits_deg(model, j)
        dh_joints.append(
            JointDH(
                **params,
                lower_deg=lower,
                upper_deg=upper,
                mass_kg=float(inertia.mass),
                com_m=tuple(float(c) for c in invert(F)[:3, :3] @ com_world + invert(F)[:3, 3]),
            )
        )
    desc = RobotDescription(
        name=name or model.name or path.stem,
        joints=tuple(dh_joints),
        tool=invert(F) @ tip,
    )
    _check_against_urdf(desc, model, joints, fid, path)
    return desc


def _limits_deg(model: pin.Model, j: int) -> tuple[float, float]:
    """A joint's limits (degrees); continuous joints get ``±CONTINUOUS_LIMIT_DEG``."""
    if model.joints[j].shortname() in _CONTINUOUS:
        return -CONTINUOUS_LIMIT_DEG, CONTINUOUS_LIMIT_DEG
    iq = model.joints[j].idx_q
    return (
        float(np.rad2deg(model.lowerPositionLimit[iq])),
        float(np.rad2deg(model.upperPositionLimit[iq])),
    )


def _urdf_q(model: pin.Model, joints: list[int], q: np.ndarray) -> np.ndarray:
    """pinocchio's configuration vector for chain angles ``q`` (rad); others neutral."""
    full = pin.neutral(model)
    for j, angle in zip(joints, q, strict=True):
        iq = model.joints[j].idx_q
        if model.joints[j].shortname() in _CONTINUOUS:
            full[iq : iq + 2] = np.cos(angle), np.sin(angle)
        else:
            full[iq] = angle
    return full


def _check_against_urdf(
    desc: RobotDescription, model: pin.Model, joints: list[int], fid: int, path: Path
) -> None:
    """Refuse a description whose FK differs from pinocchio's FK of the URDF (> 1 nm)."""
    data = model.createData()
    lim = desc.limits_rad
    q = np.random.default_rng(0).uniform(
        np.maximum(lim[:, 0], -np.pi), np.minimum(lim[:, 1], np.pi), (20, len(joints))
    )
    ours = RobotModel(desc).fk(q)
    for k in range(len(q)):
        pin.framesForwardKinematics(model, data, _urdf_q(model, joints, q[k]))
        gap = np.abs(data.oMf[fid].homogeneous - ours[k]).max()
        if gap > 1e-9:
            raise DescriptionError(
                f"{path}: the chain has no exact DH form (FK differs by {gap:.2e} at sample {k})"
            )
