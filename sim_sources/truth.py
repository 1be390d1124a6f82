"""The "true" robot of the simulated cell: the nominal description plus hidden effects.

Every effect's perturbation is evaluated once per set of conditions, so the pose with all
effects and each effect's ground-truth contribution (the pose with all effects against the
pose with all but that one) come from the same numbers.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from kinematics.effects import (
    Conditions,
    Effect,
    Perturbation,
    dh_poses,
    dh_table,
    dh_to_ctrl_delta,
)
from kinematics.model import RobotModel
from kinematics.transforms import pose_error

#: Effects that act between motor and link, so an arm-side (secondary) encoder sees them.
TRANSMISSION_EFFECTS = ("joint_compliance", "backlash", "gear_periodic")


@dataclass(frozen=True)
class TrueRobot:
    """A robot model and its hidden effects, each with its true parameters (SI)."""

    model: RobotModel
    effects: tuple[tuple[Effect, np.ndarray], ...]

    @property
    def names(self) -> tuple[str, ...]:
        return tuple(effect.name for effect, _ in self.effects)

    def perturbations(self, cond: Conditions) -> dict[str, Perturbation]:
        """Each effect's perturbation at ``cond``, by name."""
        return {e.name: e.perturbation(self.model, p, cond) for e, p in self.effects}

    def poses(
        self,
        cond: Conditions,
        perturbations: dict[str, Perturbation] | None = None,
        exclude: str | None = None,
    ) -> np.ndarray:
        """True probe poses ``T_0_S`` (N, 4, 4), optionally without effect ``exclude``."""
        desc = self.model.description
        perturbations = self.perturbations(cond) if perturbations is None else perturbations
        total = Perturbation.zero(cond.n_points, desc.n_joints)
        for name, pert in perturbations.items():
            if name != exclude:
                total = total.combine(pert)
        flange = dh_poses(desc.to_dh(cond.q) + total.dq, dh_table(desc)[None] + total.ddh)
        return total.base @ flange @ desc.tool[None] @ total.tool

    def contributions(
        self, cond: Conditions, perturbations: dict[str, Perturbation] | None = None
    ) -> dict[str, np.ndarray]:
        """Per effect, the pose error (N, 6) that removing it would undo (base frame)."""
        perturbations = self.perturbations(cond) if perturbations is None else perturbations
        full = self.poses(cond, perturbations)
        return {
            name: pose_error(full, self.poses(cond, perturbations, exclude=name))
            for name in perturbations
        }

    def deflection(self, cond: Conditions) -> np.ndarray:
        """Link-minus-motor angles (N, n) rad on the controller's axes: what secondary encoders
        add to the motor reading. Every transmission effect (elastic deflection, backlash, gear
        ripple) lies between the two encoders; zero without any of them."""
        desc = self.model.description
        dq = np.zeros_like(np.asarray(cond.q, dtype=float))
        for effect, params in self.effects:
            if effect.name in TRANSMISSION_EFFECTS:
                dq += dh_to_ctrl_delta(desc, effect.perturbation(self.model, params, cond).dq)
        return dq
