"""``joint_compliance``: each actuator twists by its torque times its compliance (1/stiffness).

Torques come from pinocchio (:meth:`RobotModel.gravity_torque`: the links, the payload and an
external tool force such as an air spring). With a J2/J3 parallelogram the actuators sit on
the controller's axes, so the DH torque maps to them by ``tau_ctrl = C^T tau_dh`` and their
deflection back by ``dq_dh = C dq_ctrl`` (``C`` = :func:`coupling_matrix`). The link lags the
motor against the holding torque, ``dq_ctrl = -c * tau_ctrl``: gravity sags the tool and a
force pushes it along itself. Parameters ``c{i}_rad_per_Nm`` (0 = rigid), linear.

A gravity balancer (e.g. the J2 spring of large robots) carries a fraction ``balancer[i]`` of
the arm's own gravity torque on controller axis ``i`` (not of the payload or tool force), so
the gear only sees the rest.
"""

from __future__ import annotations

import numpy as np

from kinematics.description import RobotDescription
from kinematics.effects._base import Conditions, Effect, Perturbation, coupling_matrix
from kinematics.errors import ConfigError
from kinematics.model import RobotModel


def actuator_torque(
    model: RobotModel, cond: Conditions, balancer: tuple[float, ...] = ()
) -> np.ndarray:
    """Holding torques (N, n) N·m on the controller's axes, gravity + payload + tool force,
    less the ``balancer`` fractions of the arm's own gravity torque."""
    desc = model.description
    q = np.asarray(cond.q, dtype=float)
    payload = cond.payload_per_point()
    tau_dh = np.empty((cond.n_points, desc.n_joints))
    for mass in np.unique(payload):
        rows = np.flatnonzero(payload == mass)
        force = None if cond.tool_force_n is None else np.asarray(cond.tool_force_n)[rows]
        tau_dh[rows] = model.gravity_torque(q[rows], payload_kg=float(mass), tool_force_n=force)
    # Rounding noise (a joint whose axis carries no load, e.g. J6 under a centred payload) is
    # zero torque, not a column of 1e-13 N·m that a fit could scale up without limit.
    tau_dh[np.abs(tau_dh) < 1e-9 * max(float(np.abs(tau_dh).max(initial=0.0)), 1.0)] = 0.0
    C = coupling_matrix(desc)
    tau = tau_dh @ C
    if any(balancer):
        tau -= np.resize(np.asarray(balancer, dtype=float), desc.n_joints) * (
            model.gravity_torque(q) @ C
        )
    return tau


def torque_need(model: RobotModel, cond: Conditions) -> str | None:
    """Why holding torques cannot be computed (no link masses, payload or tool force), or None."""
    if any(j.mass_kg > 0 for j in model.description.joints) or cond.has_loads():
        return None
    return (
        "needs holding torques: link masses (mass_kg in the description), a payload "
        "(payload_kg) or a tool force (force_x_n..); this robot and dataset give none"
    )


def compliance_deflection(
    model: RobotModel, params: np.ndarray, cond: Conditions, balancer: tuple[float, ...] = ()
) -> np.ndarray:
    """Elastic deflections (N, n) rad on the controller's axes (what secondary encoders see)."""
    return -np.asarray(params, dtype=float)[None] * actuator_torque(model, cond, balancer)


class JointCompliance(Effect):
    """Elastic joint deflection under gravity, payload and external force."""

    name = "joint_compliance"

    def __init__(self, balancer: tuple[float, ...] = ()) -> None:
        if any(not 0 <= b <= 1 for b in balancer):
            raise ConfigError(f"joint_compliance.balancer must be in [0, 1], got {balancer}")
        self.balancer = tuple(float(b) for b in balancer)

    def options(self) -> dict:
        return {"balancer": list(self.balancer)}

    def needs(self, model: RobotModel, cond: Conditions) -> str | None:
        return torque_need(model, cond)

    def parameter_names(self, desc: RobotDescription) -> tuple[str, ...]:
        return tuple(f"c{i}_rad_per_Nm" for i in range(1, desc.n_joints + 1))

    def perturbation(self, model: RobotModel, params: np.ndarray, cond: Conditions) -> Perturbation:
        desc = model.description
        params = self.checked(desc, params)
        out = Perturbation.zero(cond.n_points, desc.n_joints)
        if np.any(params != 0):
            out.dq = (
                compliance_deflection(model, params, cond, self.balancer) @ coupling_matrix(desc).T
            )
        return out
