"""``gear_periodic``: the gears' cyclic transmission error at a few harmonics of the joint angle.

Per controller joint ``i`` and order ``h``: ``dq_ctrl,i = A_ih sin(h q_i) + B_ih cos(h q_i)``
(the amplitude-phase form written linearly), mapped to DH joints by the coupling. Parameters
``gear{i}_h{h}_sin_rad`` and ``gear{i}_h{h}_cos_rad``.

>>> from kinematics.description import load_description
>>> GearPeriodic(orders=(1, 2)).parameter_names(load_description("ur10"))[:2]
('gear1_h1_sin_rad', 'gear1_h1_cos_rad')
"""

from __future__ import annotations

import numpy as np

from kinematics.description import RobotDescription
from kinematics.effects._base import Conditions, Effect, Perturbation, ctrl_to_dh_delta
from kinematics.errors import ConfigError
from kinematics.model import RobotModel


class GearPeriodic(Effect):
    """Sinusoidal joint-angle errors at harmonic ``orders`` of each joint angle."""

    name = "gear_periodic"

    def __init__(self, orders: tuple[int, ...] = (1, 2, 3)) -> None:
        if not orders or any(int(h) != h or h < 1 for h in orders):
            raise ConfigError(f"gear_periodic.orders must be positive integers, got {orders}")
        self.orders = tuple(int(h) for h in orders)

    def options(self) -> dict:
        return {"orders": list(self.orders)}

    def parameter_names(self, desc: RobotDescription) -> tuple[str, ...]:
        return tuple(
            f"gear{i}_h{h}_{part}_rad"
            for i in range(1, desc.n_joints + 1)
            for h in self.orders
            for part in ("sin", "cos")
        )

    def perturbation(self, model: RobotModel, params: np.ndarray, cond: Conditions) -> Perturbation:
        desc = model.description
        params = self.checked(desc, params).reshape(desc.n_joints, len(self.orders), 2)
        angle = np.asarray(cond.q, dtype=float)[:, :, None] * np.asarray(self.orders)[None, None]
        dq_ctrl = np.sum(
            params[None, :, :, 0] * np.sin(angle) + params[None, :, :, 1] * np.cos(angle), axis=-1
        )
        out = Perturbation.zero(cond.n_points, desc.n_joints)
        out.dq = ctrl_to_dh_delta(desc, dq_ctrl)
        return out
