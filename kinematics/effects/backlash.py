"""``backlash``: the gear play; the link rests on one flank, half the play from the middle.

Parameters ``half_play{i}_rad`` per controller joint. The flank is chosen by the approach
direction (``sign_from="approach"``: the link lags the motor, ``dq_ctrl = -h * approach``) or by
the holding torque (``sign_from="torque"``: the load pushes the link onto the flank it points to,
``dq_ctrl = -h * sign(tau)``). Mapped to DH joints by the coupling; linear in the parameters.
"""

from __future__ import annotations

import numpy as np

from kinematics.description import RobotDescription
from kinematics.effects._base import Conditions, Effect, Perturbation, ctrl_to_dh_delta
from kinematics.effects.joint_compliance import actuator_torque, torque_need
from kinematics.errors import ConfigError
from kinematics.model import RobotModel

SIGN_SOURCES = ("approach", "torque")


class Backlash(Effect):
    """Half the play per joint, signed by the approach direction or the torque sign."""

    name = "backlash"

    def __init__(self, sign_from: str = "approach") -> None:
        if sign_from not in SIGN_SOURCES:
            raise ConfigError(
                f"backlash.sign_from must be one of {SIGN_SOURCES}, got {sign_from!r}"
            )
        self.sign_from = sign_from

    def options(self) -> dict:
        return {"sign_from": self.sign_from}

    def needs(self, model: RobotModel, cond: Conditions) -> str | None:
        if self.sign_from == "torque":
            return torque_need(model, cond)
        if cond.approach is None:
            return "needs approach directions (approach1.. columns, or rows in visiting order)"
        return None

    def parameter_names(self, desc: RobotDescription) -> tuple[str, ...]:
        return tuple(f"half_play{i}_rad" for i in range(1, desc.n_joints + 1))

    def flank_sign(self, model: RobotModel, cond: Conditions) -> np.ndarray:
        """The sign (N, n) of the motion or torque that decides the flank, ±1."""
        if self.sign_from == "torque":
            return np.where(actuator_torque(model, cond) >= 0, 1.0, -1.0)
        if cond.approach is None:
            raise ConfigError("backlash with sign_from='approach' needs conditions.approach")
        return np.sign(np.asarray(cond.approach, dtype=float))

    def perturbation(self, model: RobotModel, params: np.ndarray, cond: Conditions) -> Perturbation:
        desc = model.description
        params = self.checked(desc, params)
        out = Perturbation.zero(cond.n_points, desc.n_joints)
        if np.any(params != 0):
            out.dq = ctrl_to_dh_delta(desc, -params[None] * self.flank_sign(model, cond))
        return out
