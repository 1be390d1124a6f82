"""The robot in the dashboard's 3-D view: solid links and joint housings from its DH geometry.

A robot description is DH (a URDF is turned into DH on load, ``kinematics.urdf``), so one
drawing serves both: pinocchio's forward kinematics gives every joint frame, each DH link is
two capsules (``d`` along the joint axis, then ``a`` across to the next joint), each joint is a
cylinder along its axis, and the tool is a thin capsule from the flange to the tool point.
Sizes follow the robot's reach, so a 4 m Fanuc and a 1.3 m UR10 both look like robots.
"""

from __future__ import annotations

import numpy as np
import pinocchio as pin
import rerun as rr

from kinematics.model import RobotModel

LINK_RGB = (236, 160, 60)  # its blue keeps it apart from the error colours (blue 0)
JOINT_RGB = (90, 90, 100)
TOOL_RGB = (60, 120, 220)


def reach_m(robot: RobotModel) -> float:
    """Sum of the DH link lengths ``|a| + |d|`` plus the tool offset (m): the drawing's scale."""
    links = sum(abs(j.a_m) + abs(j.d_m) for j in robot.description.joints)
    return float(links + np.linalg.norm(robot.description.tool[:3, 3]))


def skeleton(robot: RobotModel, q_ctrl: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Polyline ``(2 n + 3, 3)`` (m, base frame) from the base through every joint origin, the
    end of each link's ``d`` part, the flange to the tool point; and the joint axes ``(n, 3)``."""
    q = robot.description.to_dh(np.asarray(q_ctrl, dtype=float)[None])[0]
    pin.framesForwardKinematics(robot.model, robot.data, q)
    points, axes = [np.zeros(3)], []
    for i, j in enumerate(robot.description.joints, start=1):
        oMi = robot.data.oMi[i]
        points.append(oMi.translation.copy())
        points.append(oMi.act(np.array([0.0, 0.0, j.d_m])))
        axes.append(oMi.rotation[:, 2].copy())
    points.append(robot.data.oMf[robot.model.getFrameId("flange")].translation.copy())
    points.append(robot.data.oMf[robot.model.getFrameId("tool")].translation.copy())
    return np.array(points), np.array(axes)


def z_to(u: np.ndarray) -> np.ndarray:
    """Quaternions ``(N, 4)`` (xyzw) turning +z onto the unit vectors ``u`` ``(N, 3)``."""
    u = np.asarray(u, dtype=float)
    z = np.array([0.0, 0.0, 1.0])
    w = 1.0 + u @ z
    xyz = np.cross(z, u)
    flip = w < 1e-9  # pointing down: half a turn about x
    quat = np.column_stack([xyz, w])
    quat[flip] = [1.0, 0.0, 0.0, 0.0]
    return quat / np.linalg.norm(quat, axis=1, keepdims=True)


def segments(points: np.ndarray, min_length_m: float = 1e-6) -> tuple[np.ndarray, ...]:
    """Start points, lengths (m) and +z-to-direction quaternions of a polyline's segments
    longer than ``min_length_m``."""
    d = np.diff(points, axis=0)
    length = np.linalg.norm(d, axis=1)
    keep = length > min_length_m
    return points[:-1][keep], length[keep], z_to(d[keep] / length[keep, None])


def robot_archetypes(robot: RobotModel, q_ctrl: np.ndarray) -> dict[str, rr.AsComponents]:
    """The robot at ``q_ctrl`` (rad, controller angles) as Rerun archetypes by entity name:
    ``links`` and ``tool`` (capsules), ``joints`` (cylinders along the joint axes)."""
    points, axes = skeleton(robot, q_ctrl)
    r = 0.03 * reach_m(robot)
    start, length, quat = segments(points[:-1])
    t_start, t_length, t_quat = segments(points[-2:])
    n = len(axes)
    return {
        "links": rr.Capsules3D(
            lengths=length, radii=r, translations=start, quaternions=quat, colors=LINK_RGB
        ),
        "joints": rr.Cylinders3D(
            lengths=np.full(n, 3.0 * r),
            radii=1.3 * r,
            centers=points[1 : 2 * n : 2],
            quaternions=z_to(axes),
            colors=JOINT_RGB,
            labels=[f"J{i}" for i in range(1, n + 1)],
        ),
        "tool": rr.Capsules3D(
            lengths=t_length,
            radii=0.3 * r,
            translations=t_start,
            quaternions=t_quat,
            colors=TOOL_RGB,
        ),
    }
