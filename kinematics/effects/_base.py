"""The ``Effect`` family: physical additions to the nominal robot model, and the perturbed FK.

An effect maps its parameters (physically meaningful, SI units) and the per-point conditions
(joint angles, time, temperatures, approach direction, loads) to a :class:`Perturbation`:
joint-angle offsets, DH-parameter deltas, and base/tool frame corrections. The simulator's
"true" robot and the discrepancy workflow's identification both evaluate
:func:`perturbed_poses`, so an effect is defined once and used by both.

Per point k the true probe pose in the base frame is
``B_k · prod_i Rz(q_dh,i + dq_k,i + offset_i + doffset_k,i) Fixed(dh_i + ddh_k,i) · T_6_S · S_k``.
"""

from __future__ import annotations

import abc
from dataclasses import dataclass
from typing import ClassVar

import numpy as np

from kinematics.description import RobotDescription
from kinematics.model import RobotModel

#: Columns of a DH table: a (m), d (m), alpha (rad), beta (rad), offset (rad).
DH_FIELDS = ("a", "d", "alpha", "beta", "offset")


@dataclass(frozen=True, kw_only=True)
class Conditions:
    """What effects may depend on, per point (``N`` points, ``n`` joints; SI units)."""

    q: np.ndarray
    t: np.ndarray
    temperatures: np.ndarray | None = None
    temperature_names: tuple[str, ...] = ()
    approach: np.ndarray | None = None
    payload_kg: float = 0.0
    tool_force_n: np.ndarray | None = None

    @property
    def n_points(self) -> int:
        return int(np.shape(self.q)[0])


@dataclass(kw_only=True)
class Perturbation:
    """What effects change: DH-joint offsets ``dq`` (N, n) rad, DH deltas ``ddh`` (N, n, 5),
    and frame corrections ``base`` / ``tool`` (N, 4, 4) applied left / right."""

    dq: np.ndarray
    ddh: np.ndarray
    base: np.ndarray
    tool: np.ndarray

    @classmethod
    def zero(cls, n_points: int, n_joints: int) -> Perturbation:
        eye = np.broadcast_to(np.eye(4), (n_points, 4, 4)).copy()
        return cls(
            dq=np.zeros((n_points, n_joints)),
            ddh=np.zeros((n_points, n_joints, len(DH_FIELDS))),
            base=eye,
            tool=eye.copy(),
        )

    def combine(self, other: Perturbation) -> Perturbation:
        """Both perturbations at once (offsets add; frames compose)."""
        return Perturbation(
            dq=self.dq + other.dq,
            ddh=self.ddh + other.ddh,
            base=other.base @ self.base,
            tool=self.tool @ other.tool,
        )


class Effect(abc.ABC):
    """One physical effect of DESIGN.md's vocabulary, with named parameters."""

    name: ClassVar[str]

    @abc.abstractmethod
    def parameter_names(self, desc: RobotDescription) -> tuple[str, ...]:
        """Names (with units, e.g. ``k2_Nm_per_rad``) of this effect's parameters."""

    @abc.abstractmethod
    def perturbation(self, model: RobotModel, params: np.ndarray, cond: Conditions) -> Perturbation:
        """The change this effect makes at each point for parameters ``params``."""

    def zero_parameters(self, desc: RobotDescription) -> np.ndarray:
        """Parameters at which the effect is absent (zeros unless a member says otherwise)."""
        return np.zeros(len(self.parameter_names(desc)))


def dh_table(desc: RobotDescription) -> np.ndarray:
    """The nominal DH table ``(n, 5)`` in :data:`DH_FIELDS` order (m, rad)."""
    return np.array(
        [
            [
                j.a_m,
                j.d_m,
                np.deg2rad(j.alpha_deg),
                np.deg2rad(j.beta_deg),
                np.deg2rad(j.offset_deg),
            ]
            for j in desc.joints
        ]
    )


def dh_poses(q_dh: np.ndarray, dh: np.ndarray) -> np.ndarray:
    """Flange poses ``(N, 4, 4)`` from DH joint variables ``(N, n)`` and a DH table per point
    ``(N, n, 5)`` (or shared ``(n, 5)``); vectorised over points."""
    q_dh = np.atleast_2d(q_dh)
    N, n = q_dh.shape
    dh = np.broadcast_to(dh, (N, n, len(DH_FIELDS)))
    T = np.broadcast_to(np.eye(4), (N, 4, 4)).copy()
    for i in range(n):
        a, d, al, be, off = (dh[:, i, k] for k in range(5))
        th = q_dh[:, i] + off
        ct, st = np.cos(th), np.sin(th)
        ca, sa = np.cos(al), np.sin(al)
        cb, sb = np.cos(be), np.sin(be)
        # Rz(th) Tx(a) Tz(d) Rx(al) Ry(be), written out.
        A = np.zeros((N, 4, 4))
        R_xy = np.stack(
            [
                np.stack([cb, np.zeros_like(cb), sb], -1),
                np.stack([sa * sb, ca, -sa * cb], -1),
                np.stack([-ca * sb, sa, ca * cb], -1),
            ],
            axis=-2,
        )
        Rz = np.zeros((N, 3, 3))
        Rz[:, 0, 0], Rz[:, 0, 1], Rz[:, 1, 0], Rz[:, 1, 1], Rz[:, 2, 2] = ct, -st, st, ct, 1.0
        A[:, :3, :3] = Rz @ R_xy
        A[:, :3, 3] = np.stack([a * ct, a * st, d], -1)
        A[:, 3, 3] = 1.0
        T = T @ A
    return T


def perturbed_poses(
    model: RobotModel, cond: Conditions, effects: list[tuple[Effect, np.ndarray]]
) -> np.ndarray:
    """Probe poses ``T_0_S`` ``(N, 4, 4)`` of the robot with ``effects`` (each with its params)."""
    desc = model.description
    total = Perturbation.zero(cond.n_points, desc.n_joints)
    for effect, params in effects:
        total = total.combine(effect.perturbation(model, np.asarray(params, dtype=float), cond))
    flange = dh_poses(desc.to_dh(cond.q) + total.dq, dh_table(desc)[None] + total.ddh)
    return total.base @ flange @ desc.tool[None] @ total.tool
