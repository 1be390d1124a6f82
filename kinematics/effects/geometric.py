"""``geometric``: constant deviations of every DH-Hayati parameter from the description.

Five parameters per joint in :data:`DH_FIELDS` order: ``a{i}_m``, ``d{i}_m``,
``alpha{i}_rad``, ``beta{i}_rad``, ``offset{i}_rad``. Linear in the DH table, zero = nominal.

>>> from kinematics.description import load_description
>>> Geometric().parameter_names(load_description("ur10"))[:3]
('a1_m', 'd1_m', 'alpha1_rad')
"""

from __future__ import annotations

import numpy as np

from kinematics.description import RobotDescription
from kinematics.effects._base import DH_FIELDS, Conditions, Effect, Perturbation
from kinematics.model import RobotModel

_UNITS = {"a": "m", "d": "m", "alpha": "rad", "beta": "rad", "offset": "rad"}


class Geometric(Effect):
    """DH parameter deviations ``ddh`` (n, 5), the same at every point."""

    name = "geometric"

    def parameter_names(self, desc: RobotDescription) -> tuple[str, ...]:
        return tuple(f"{f}{i}_{_UNITS[f]}" for i in range(1, desc.n_joints + 1) for f in DH_FIELDS)

    def perturbation(self, model: RobotModel, params: np.ndarray, cond: Conditions) -> Perturbation:
        desc = model.description
        params = self.checked(desc, params)
        out = Perturbation.zero(cond.n_points, desc.n_joints)
        out.ddh[:] = params.reshape(desc.n_joints, len(DH_FIELDS))[None]
        return out
