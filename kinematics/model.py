"""A pinocchio model of a serial arm built from its description; batched FK and gravity.

Each joint is a revolute about its local z axis; the fixed part of the DH-Hayati matrix,
``Tx(a) Tz(d) Rx(alpha) Ry(beta)``, becomes the placement of the next joint (and of the flange
after the last one). Joint offsets are folded into the placements as ``Rz(offset)``.

>>> from kinematics.description import load_description
>>> m = RobotModel(load_description("ur10"))
>>> m.fk(np.zeros((2, 6))).shape
(2, 4, 4)
"""

from __future__ import annotations

import numpy as np
import pinocchio as pin

from kinematics.description_types import JointDH, RobotDescription

GRAVITY_M_S2 = np.array([0.0, 0.0, -9.81])


def dh_fixed(j: JointDH) -> np.ndarray:
    """``Tx(a) Tz(d) Rx(alpha) Ry(beta)``: the constant part of one joint's transform."""
    ca, sa = np.cos(np.deg2rad(j.alpha_deg)), np.sin(np.deg2rad(j.alpha_deg))
    cb, sb = np.cos(np.deg2rad(j.beta_deg)), np.sin(np.deg2rad(j.beta_deg))
    Rx = np.array([[1, 0, 0], [0, ca, -sa], [0, sa, ca]])
    Ry = np.array([[cb, 0, sb], [0, 1, 0], [-sb, 0, cb]])
    T = np.eye(4)
    T[:3, :3] = Rx @ Ry
    T[:3, 3] = [j.a_m, 0.0, j.d_m]
    return T


def rot_z(angle: float) -> np.ndarray:
    """Homogeneous rotation about z by ``angle`` (rad)."""
    c, s = np.cos(angle), np.sin(angle)
    T = np.eye(4)
    T[:2, :2] = [[c, -s], [s, c]]
    return T


def build_pinocchio_model(desc: RobotDescription) -> pin.Model:
    """The pinocchio model of ``desc``; frames ``flange`` (frame 6) and ``tool`` (frame S)."""
    model = pin.Model()
    model.name = desc.name
    parent = 0
    placement = np.eye(4)
    for i, j in enumerate(desc.joints, start=1):
        M = placement @ rot_z(np.deg2rad(j.offset_deg))
        jid = model.addJoint(parent, pin.JointModelRZ(), pin.SE3(M), f"joint{i}")
        # The link's mass acts in DH frame i, i.e. after this joint's fixed part.
        fixed = dh_fixed(j)
        com_in_joint = fixed[:3, :3] @ np.asarray(j.com_m) + fixed[:3, 3]
        inertia = pin.Inertia.FromSphere(j.mass_kg, 0.05) if j.mass_kg > 0 else pin.Inertia.Zero()
        inertia = pin.Inertia(inertia.mass, com_in_joint, inertia.inertia)
        model.appendBodyToJoint(jid, inertia, pin.SE3.Identity())
        model.addJointFrame(jid)
        parent = jid
        placement = fixed
    flange = model.addFrame(
        pin.Frame("flange", parent, 0, pin.SE3(placement), pin.FrameType.OP_FRAME)
    )
    model.addFrame(
        pin.Frame("tool", parent, flange, pin.SE3(placement @ desc.tool), pin.FrameType.OP_FRAME)
    )
    model.gravity = pin.Motion(GRAVITY_M_S2, np.zeros(3))
    return model


class RobotModel:
    """Forward kinematics and gravity torques of one description (controller angles in, SI out)."""

    def __init__(self, desc: RobotDescription) -> None:
        self.description = desc
        self.model = build_pinocchio_model(desc)
        self.data = self.model.createData()
        self._flange = self.model.getFrameId("flange")
        self._tool = self.model.getFrameId("tool")

    def fk(self, q_ctrl: np.ndarray, frame: str = "tool") -> np.ndarray:
        """Poses ``T_0_S`` (or ``T_0_6`` with ``frame="flange"``) ``(N, 4, 4)`` for ``(N, n)``."""
        fid = self._tool if frame == "tool" else self._flange
        q = self.description.to_dh(np.atleast_2d(q_ctrl))
        out = np.empty((q.shape[0], 4, 4))
        for k in range(q.shape[0]):
            pin.framesForwardKinematics(self.model, self.data, q[k])
            out[k] = self.data.oMf[fid].homogeneous
        return out

    def gravity_torque(
        self,
        q_ctrl: np.ndarray,
        payload_kg: float = 0.0,
        payload_com_m: tuple[float, float, float] = (0.0, 0.0, 0.0),
        tool_force_n: np.ndarray | None = None,
    ) -> np.ndarray:
        """Joint torques (N·m, DH joint axes) holding the arm against gravity, ``(N, n)``.

        ``payload_com_m`` is in the flange frame; ``tool_force_n`` ``(N, 3)`` is an external force
        in the base frame acting at the tool point (e.g. an air spring), added via ``J^T f``.
        """
        q = self.description.to_dh(np.atleast_2d(q_ctrl))
        model = self.model
        if payload_kg > 0:
            model = self.model.copy()
            flange = model.frames[self._flange]
            com = flange.placement.act(np.asarray(payload_com_m, dtype=float))
            model.inertias[flange.parentJoint] += pin.Inertia.FromSphere(
                payload_kg, 0.01
            ).se3Action(pin.SE3(np.eye(3), com))
        data = model.createData()
        tau = np.empty_like(q)
        for k in range(q.shape[0]):
            tau[k] = pin.computeGeneralizedGravity(model, data, q[k])
            if tool_force_n is not None:
                J = pin.computeFrameJacobian(
                    model, data, q[k], self._tool, pin.ReferenceFrame.LOCAL_WORLD_ALIGNED
                )
                tau[k] -= J[:3].T @ np.asarray(tool_force_n[k], dtype=float)
        return tau

    def fk_and_jacobian(self, q_ctrl: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Tool poses ``(N, 4, 4)`` and Jacobians ``(N, 6, n)`` w.r.t. DH joint variables
        (world-aligned at the tool), one kinematics pass per pose."""
        q = self.description.to_dh(np.atleast_2d(q_ctrl))
        poses = np.empty((q.shape[0], 4, 4))
        jacobians = np.empty((q.shape[0], 6, q.shape[1]))
        for k in range(q.shape[0]):
            jacobians[k] = pin.computeFrameJacobian(
                self.model, self.data, q[k], self._tool, pin.ReferenceFrame.LOCAL_WORLD_ALIGNED
            )
            poses[k] = pin.updateFramePlacement(self.model, self.data, self._tool).homogeneous
        return poses, jacobians

    def jacobian(self, q_ctrl: np.ndarray) -> np.ndarray:
        """Tool Jacobians ``(N, 6, n)`` w.r.t. DH joint variables (world-aligned at the tool)."""
        return self.fk_and_jacobian(q_ctrl)[1]
