"""``base_frame`` / ``tool_frame``: constant errors of the believed ``T_W_0`` and ``T_6_S``.

Six parameters each: a translation (m) and a rotation vector (rad). The base correction acts
on the left of the flange pose (in the base frame), the tool correction on the right (in the
probe frame), so the true pose is ``B · T_0_6 · T_6_S · S``.
"""

from __future__ import annotations

import numpy as np

from kinematics.description import RobotDescription
from kinematics.effects._base import Conditions, Effect, Perturbation, frame_correction
from kinematics.model import RobotModel

_SUFFIXES = ("x_m", "y_m", "z_m", "rx_rad", "ry_rad", "rz_rad")


class _FrameOffset(Effect):
    """A constant rigid correction of one frame."""

    side: str

    def parameter_names(self, desc: RobotDescription) -> tuple[str, ...]:
        return tuple(f"{self.side}_{s}" for s in _SUFFIXES)

    def perturbation(self, model: RobotModel, params: np.ndarray, cond: Conditions) -> Perturbation:
        params = self.checked(model.description, params)
        out = Perturbation.zero(cond.n_points, model.description.n_joints)
        correction = np.broadcast_to(frame_correction(params[:3], params[3:]), out.base.shape)
        setattr(out, self.side, correction.copy())
        return out


class BaseFrame(_FrameOffset):
    """Error of the robot base in the tracker frame, ``T_W_0``."""

    name = "base_frame"
    side = "base"


class ToolFrame(_FrameOffset):
    """Error of the probe on the flange, ``T_6_S``."""

    name = "tool_frame"
    side = "tool"
