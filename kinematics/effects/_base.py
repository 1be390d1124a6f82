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
from collections.abc import Callable
from dataclasses import dataclass
from typing import ClassVar

import numpy as np
from scipy.spatial.transform import Rotation

from kinematics.description import RobotDescription
from kinematics.errors import ConfigError
from kinematics.model import RobotModel

#: Columns of a DH table: a (m), d (m), alpha (rad), beta (rad), offset (rad).
DH_FIELDS = ("a", "d", "alpha", "beta", "offset")


@dataclass(frozen=True, kw_only=True)
class Conditions:
    """What effects may depend on, per point (``N`` points, ``n`` joints; SI units).

    ``q`` controller angles (N, n) rad; ``t`` (N,) s; ``temperatures`` (N, k) °C named by
    ``temperature_names`` (without the ``temp_`` prefix); ``approach`` (N, n) the sign (±1) of
    each controller joint's last motion before the point; ``payload_kg`` a scalar or (N,) mass
    at the flange; ``tool_force_n`` (N, 3) an external force at the tool point, base frame.
    """

    q: np.ndarray
    t: np.ndarray
    temperatures: np.ndarray | None = None
    temperature_names: tuple[str, ...] = ()
    approach: np.ndarray | None = None
    payload_kg: float | np.ndarray = 0.0
    tool_force_n: np.ndarray | None = None

    def __post_init__(self) -> None:
        q = np.asarray(self.q)
        if q.ndim != 2:
            raise ConfigError(f"conditions.q must be (N, n), got shape {q.shape}")
        N, n = q.shape
        expected = {
            "t": (N,),
            "temperatures": (N, len(self.temperature_names)),
            "approach": (N, n),
            "tool_force_n": (N, 3),
        }
        for key, shape in expected.items():
            value = getattr(self, key)
            if value is not None and np.shape(value) != shape:
                raise ConfigError(
                    f"conditions.{key} must have shape {shape}, got {np.shape(value)}"
                )
        if np.ndim(self.payload_kg) not in (0, 1) or np.size(self.payload_kg) not in (1, N):
            raise ConfigError(
                f"conditions.payload_kg must be a scalar or ({N},), got {np.shape(self.payload_kg)}"
            )

    @property
    def n_points(self) -> int:
        return int(np.shape(self.q)[0])

    def has_loads(self) -> bool:
        """Whether a payload or a tool force acts at any point."""
        force = self.tool_force_n is not None and np.any(np.asarray(self.tool_force_n) != 0)
        return bool(force or np.any(self.payload_per_point() != 0))

    def payload_per_point(self) -> np.ndarray:
        """The payload (N,) kg, whether given as a scalar or per point."""
        return np.broadcast_to(np.asarray(self.payload_kg, dtype=float), (self.n_points,))


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
        """Names (with units, e.g. ``c2_rad_per_Nm``) of this effect's parameters."""

    @abc.abstractmethod
    def perturbation(self, model: RobotModel, params: np.ndarray, cond: Conditions) -> Perturbation:
        """The change this effect makes at each point for parameters ``params``."""

    def needs(self, model: RobotModel, cond: Conditions) -> str | None:
        """What this effect needs that the robot or the data lacks (one phrase), else None."""
        return None

    def zero_parameters(self, desc: RobotDescription) -> np.ndarray:
        """Parameters at which the effect is absent (zeros unless a member says otherwise)."""
        return np.zeros(len(self.parameter_names(desc)))

    def options(self) -> dict:
        """Constructor options that change the effect (JSON-able, for metadata); none by default."""
        return {}

    def checked(self, desc: RobotDescription, params: np.ndarray) -> np.ndarray:
        """``params`` as a finite float vector of the right length, else :class:`ConfigError`."""
        params = np.asarray(params, dtype=float).reshape(-1)
        expected = len(self.parameter_names(desc))
        if params.size != expected:
            raise ConfigError(
                f"effect {self.name!r}: expected {expected} parameters, got {params.size}"
            )
        if not np.all(np.isfinite(params)):
            raise ConfigError(f"effect {self.name!r}: parameters must be finite, got {params}")
        return params


class Restricted(Effect):
    """An effect with only the parameters at indices ``free`` estimated (the others held at 0).

    Identification keeps the identifiable subset of an effect's parameters this way.
    """

    def __init__(
        self, effect: Effect, desc: RobotDescription, free: tuple[int, ...] | None = None
    ) -> None:
        self.effect = effect
        self.name = effect.name
        self._all = effect.parameter_names(desc)
        self.free = tuple(range(len(self._all))) if free is None else tuple(free)

    def parameter_names(self, desc: RobotDescription) -> tuple[str, ...]:
        return tuple(self._all[i] for i in self.free)

    def full(self, params: np.ndarray) -> np.ndarray:
        """The wrapped effect's whole parameter vector (the held ones zero)."""
        x = np.zeros(len(self._all))
        x[list(self.free)] = params
        return x

    def options(self) -> dict:
        return self.effect.options()

    def needs(self, model: RobotModel, cond: Conditions) -> str | None:
        return self.effect.needs(model, cond)

    def perturbation(self, model: RobotModel, params: np.ndarray, cond: Conditions) -> Perturbation:
        return self.effect.perturbation(model, self.full(params), cond)


def coupling_matrix(desc: RobotDescription) -> np.ndarray:
    """``C = d q_dh / d q_ctrl`` (n, n): controller-joint deltas map to DH deltas as ``C dq``.

    >>> from kinematics.description import load_description
    >>> coupling_matrix(load_description("fanuc_m900ib700"))[2, :3].tolist()
    [0.0, 1.0, 1.0]
    """
    return desc.to_dh(np.eye(desc.n_joints)).T


def ctrl_to_dh_delta(desc: RobotDescription, dq_ctrl: np.ndarray) -> np.ndarray:
    """Joint-angle deltas on the controller's axes (N, n) -> DH joint deltas (N, n), rad."""
    return np.asarray(dq_ctrl, dtype=float) @ coupling_matrix(desc).T


def dh_to_ctrl_delta(desc: RobotDescription, dq_dh: np.ndarray) -> np.ndarray:
    """DH joint deltas (N, n) -> deltas on the controller's axes (N, n), rad."""
    return np.linalg.solve(coupling_matrix(desc), np.asarray(dq_dh, dtype=float).T).T


def frame_correction(xyz_m: np.ndarray, rotvec_rad: np.ndarray) -> np.ndarray:
    """Rigid transforms ``(..., 4, 4)`` from translations (m) and rotation vectors (rad)."""
    xyz_m = np.asarray(xyz_m, dtype=float)
    rotvec_rad = np.asarray(rotvec_rad, dtype=float)
    R = Rotation.from_rotvec(rotvec_rad.reshape(-1, 3)).as_matrix()
    T = np.zeros((R.shape[0], 4, 4))
    T[:, :3, :3] = R
    T[:, :3, 3] = xyz_m.reshape(-1, 3)
    T[:, 3, 3] = 1.0
    return T.reshape(rotvec_rad.shape[:-1] + (4, 4))


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


def dh_frames(q_dh: np.ndarray, dh: np.ndarray) -> np.ndarray:
    """Frames ``T_0_i`` ``(N, n + 1, 4, 4)`` (``i = 0`` the base, ``n`` the flange) from DH joint
    variables ``(N, n)`` and a DH table per point ``(N, n, 5)`` (or shared ``(n, 5)``);
    vectorised over points. Joint ``i`` turns about the z axis of frame ``i - 1``."""
    dh = np.asarray(dh, dtype=float)
    return _chain(np.atleast_2d(q_dh) + dh[..., 4], _fixed_parts(dh))


def dh_poses(q_dh: np.ndarray, dh: np.ndarray) -> np.ndarray:
    """Flange poses ``(N, 4, 4)`` from DH joint variables ``(N, n)`` and a DH table per point
    ``(N, n, 5)`` (or shared ``(n, 5)``); vectorised over points."""
    return dh_frames(q_dh, dh)[:, -1]


#: From this many poses on, :func:`sensor_jacobians` computes in one numpy batch.
_BATCH_FROM = 5


def sensor_jacobians(
    desc: RobotDescription,
) -> Callable[[np.ndarray], tuple[np.ndarray, np.ndarray]]:
    """The function from controller angles ``(N, n)`` to nominal sensor poses ``T_0_S``
    ``(N, 4, 4)`` and sensor-point Jacobians ``(N, 6, n)`` (base-frame axes, rows ``v, w``,
    per controller joint), one numpy batch.

    What :class:`kinematics.model.RobotModel` gives (``fk``, ``jacobian``) without its per-pose
    Python loop, and with the description's constants prepared once: the learner encodes one
    pose per prediction and hundreds per update. Below :data:`_BATCH_FROM` poses pinocchio's
    loop is the faster of the two (one pose: ~30 µs against ~150 µs), so it answers those.
    """
    table = dh_table(desc)
    fixed, offsets = _fixed_parts(table), table[:, 4]
    coupling, tool = coupling_matrix(desc), desc.tool
    model = RobotModel(desc)
    i, j = [1, 2, 0], [2, 0, 1]

    def poses_and_jacobians(q_ctrl: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        q_ctrl = np.atleast_2d(q_ctrl)
        if q_ctrl.shape[0] < _BATCH_FROM:
            poses, jacobians = model.fk_and_jacobian(q_ctrl)
            return poses, jacobians @ coupling
        frames = _chain(desc.to_dh(q_ctrl) + offsets, fixed)
        T = frames[:, -1] @ tool
        z = frames[:, :-1, :3, 2]
        lever = T[:, None, :3, 3] - frames[:, :-1, :3, 3]
        v = z[..., i] * lever[..., j] - z[..., j] * lever[..., i]  # z × lever
        return T, np.concatenate([v, z], axis=-1).transpose(0, 2, 1) @ coupling

    return poses_and_jacobians


def _fixed_parts(dh: np.ndarray) -> np.ndarray:
    """The constant factor ``Tx(a) Tz(d) Rx(alpha) Ry(beta)`` of each joint, ``(..., n, 4, 4)``."""
    a, d, al, be = (dh[..., k] for k in range(4))
    ca, sa, cb, sb = np.cos(al), np.sin(al), np.cos(be), np.sin(be)
    fixed = np.zeros(a.shape + (4, 4))
    fixed[..., 0, 0], fixed[..., 0, 2], fixed[..., 0, 3] = cb, sb, a
    fixed[..., 1, 0], fixed[..., 1, 1], fixed[..., 1, 2] = sa * sb, ca, -sa * cb
    fixed[..., 2, 0], fixed[..., 2, 1], fixed[..., 2, 2] = -ca * sb, sa, ca * cb
    fixed[..., 2, 3], fixed[..., 3, 3] = d, 1.0
    return fixed


def _chain(theta: np.ndarray, fixed: np.ndarray) -> np.ndarray:
    """Frames ``(N, n + 1, 4, 4)`` of ``prod_i Rz(theta_i) fixed_i`` for joint angles ``(N, n)``
    (DH variable plus offset): ``Rz`` mixes the first two rows of each fixed part. Computed
    joint-major, so each step multiplies contiguous ``(N, 4, 4)`` stacks."""
    N, n = theta.shape
    fixed = np.moveaxis(np.broadcast_to(fixed, (N, n, 4, 4)), 1, 0)
    c, s = np.cos(theta).T[..., None], np.sin(theta).T[..., None]
    A = np.array(fixed)
    A[..., 0, :] = c * fixed[..., 0, :] - s * fixed[..., 1, :]
    A[..., 1, :] = s * fixed[..., 0, :] + c * fixed[..., 1, :]
    frames = np.empty((n + 1, N, 4, 4))
    frames[0] = np.eye(4)
    for k in range(n):
        np.matmul(frames[k], A[k], out=frames[k + 1])
    return frames.transpose(1, 0, 2, 3)


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
