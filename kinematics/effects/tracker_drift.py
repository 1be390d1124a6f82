"""``tracker_drift``: the tracker frame creeps with time, so the base seems to move.

The apparent base correction at time ``t`` (s) is a translation ``v t`` and a rotation by the
rotation vector ``w t``, both in the robot base frame. Parameters ``vx_m_per_s, vy_m_per_s,
vz_m_per_s, wx_rad_per_s, wy_rad_per_s, wz_rad_per_s``; linear in ``v``, smooth in ``w``.
"""

from __future__ import annotations

import numpy as np

from kinematics.description import RobotDescription
from kinematics.effects._base import Conditions, Effect, Perturbation, frame_correction
from kinematics.model import RobotModel

PARAMETER_NAMES = (
    "vx_m_per_s",
    "vy_m_per_s",
    "vz_m_per_s",
    "wx_rad_per_s",
    "wy_rad_per_s",
    "wz_rad_per_s",
)


class TrackerDrift(Effect):
    """A base correction growing linearly with time from ``t = 0``."""

    name = "tracker_drift"

    def needs(self, model: RobotModel, cond: Conditions) -> str | None:
        if np.ptp(np.asarray(cond.t, dtype=float)) <= 0:
            return "needs time stamps that vary (column t)"
        return None

    def parameter_names(self, desc: RobotDescription) -> tuple[str, ...]:
        return PARAMETER_NAMES

    def perturbation(self, model: RobotModel, params: np.ndarray, cond: Conditions) -> Perturbation:
        params = self.checked(model.description, params)
        t = np.asarray(cond.t, dtype=float).reshape(-1, 1)
        out = Perturbation.zero(cond.n_points, model.description.n_joints)
        out.base = frame_correction(t * params[None, :3], t * params[None, 3:])
        return out
