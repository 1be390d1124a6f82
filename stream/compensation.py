"""Compensation maths (pure): the predicted pose error at a command and the corrected command.

The corrected command ``q_c`` solves ``apply_error(FK(q_c), e(q_c)) = T*``: the pose the
nominal model plus the learned error predicts lands on the target ``T*``. It is found by
Levenberg-Marquardt steps ``q <- q + J^T (J J^T + d^2 I)^-1 pose_error(T*, predicted(q))``
with the pinocchio tool Jacobian (DH joint variables, mapped to controller angles through the
J2/J3 coupling); the damping ``d`` grows when a step does not help, which keeps corrections
small near singular poses.
An answer is marked untrusted when the epistemic standard deviation of a position component
exceeds ``epistemic_limit_mm`` (the model has not seen data like this) and, in
:mod:`stream.compensation_guard`, when a joint lies more than ``envelope_margin_deg`` outside
the angles the model was trained on or a thermometer more than ``envelope_margin_k`` outside
the temperatures (:mod:`learner.envelope`).

Near a singular pose the damped steps cannot reach the target within ``max_iterations``: a
millimetre there takes a large joint motion. What happens then is the configured ``policy``
(:data:`POLICIES`, applied by :mod:`stream.compensation_guard`): ``refuse`` answers the
uncorrected command, ``flag`` answers the partial correction the solver reached, both
``trusted: false``; ``best_effort`` (:func:`best_effort`) solves again with the position first
(the orientation rows weighed by ``best_effort_rotation_weight``, m per rad) and joint motions
up to ``joint_motion_limit_rad`` from the command: trusted when the position lands, with the
orientation it gave up in ``residual_rad``; flagged when it does not land. On the simulated
reference cell the commands that do not land sit at the stretched elbow (J2/J3 boundary
singularity), where the nominal position and orientation together are out of the predicted
arm's reach but the position alone is not (BENCHMARKS.md).
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping
from dataclasses import dataclass, replace
from typing import ClassVar

import numpy as np

from kinematics.errors import ConfigError, DatasetError
from kinematics.model import RobotModel
from kinematics.transforms import apply_error, pose_error, transform_from_xyz_quat
from learner.envelope import MARGIN_DEG, MARGIN_K
from learner.features import features
from learner.model import ErrorModel
from wire import JOINT_LIMIT_RAD, RejectedMessageError, check_finite

#: What compensation does with a command the solver cannot land (see the module doc).
POLICIES = ("refuse", "flag", "best_effort")


@dataclass(frozen=True, kw_only=True)
class CompensationConfig:
    """Trust limits (epistemic std, mm; how far past the trained joint angles, deg, and
    temperatures, K), interval level, the corrected-command iteration (limits, the initial
    damping ``d``, the largest joint step per iteration, rad) and the policy for commands it
    cannot land: :data:`POLICIES`, with best effort's largest joint motion from the command
    (rad, any joint), its iterations and its step (rad)."""

    epistemic_limit_mm: float = 0.5
    envelope_margin_deg: float = MARGIN_DEG
    envelope_margin_k: float = MARGIN_K
    level: float = 0.9
    max_iterations: int = 50
    tolerance_m: float = 1e-7
    damping: float = 1e-6
    max_step_rad: float = 0.01
    policy: str = "flag"
    joint_motion_limit_rad: float = 0.5
    best_effort_iterations: int = 400
    best_effort_step_rad: float = 0.05
    best_effort_rotation_weight: float = 0.01

    def __post_init__(self) -> None:
        if self.policy not in POLICIES:
            raise ConfigError(
                f"compensation.policy must be one of {', '.join(POLICIES)}, got {self.policy!r}"
            )
        if not (math.isfinite(self.joint_motion_limit_rad) and self.joint_motion_limit_rad > 0):
            raise ConfigError(
                "compensation.joint_motion_limit_rad must be > 0, got "
                f"{self.joint_motion_limit_rad}"
            )
        if not 0 <= self.best_effort_rotation_weight <= 1:
            raise ConfigError(
                "compensation.best_effort_rotation_weight must be in [0, 1] m/rad, got "
                f"{self.best_effort_rotation_weight}"
            )
        if self.best_effort_iterations < 1 or not self.best_effort_step_rad > 0:
            raise ConfigError(
                "compensation.best_effort_iterations must be >= 1 and best_effort_step_rad > 0, "
                f"got {self.best_effort_iterations}, {self.best_effort_step_rad}"
            )
        if not (math.isfinite(self.epistemic_limit_mm) and self.epistemic_limit_mm > 0):
            raise ConfigError(
                f"compensation.epistemic_limit_mm must be > 0, got {self.epistemic_limit_mm}"
            )
        for name in ("envelope_margin_deg", "envelope_margin_k"):
            value = getattr(self, name)
            if not (math.isfinite(value) and value >= 0):
                raise ConfigError(f"compensation.{name} must be >= 0, got {value}")
        if not 0 < self.level < 1:
            raise ConfigError(f"compensation.level must be in (0, 1), got {self.level}")
        if not (self.damping >= 0 and self.max_step_rad > 0):
            raise ConfigError(
                f"compensation.damping must be >= 0 and max_step_rad > 0, got {self.damping}, "
                f"{self.max_step_rad}"
            )
        if self.max_iterations < 1:
            raise ConfigError(
                f"compensation.max_iterations must be >= 1, got {self.max_iterations}"
            )


@dataclass(frozen=True, kw_only=True)
class CompensationRequest:
    """Joint angles ``q`` (rad) to compensate, or a base-frame ``target`` pose (m, xyzw) with a
    seed ``q``; optional temperatures (°C, by name) and deflections (rad) as features."""

    SCHEMA: ClassVar[str] = "robocal.compensate.request"
    q: tuple[float, ...]
    target_xyz: tuple[float, float, float] | None = None
    target_quat: tuple[float, float, float, float] | None = None
    temperatures: Mapping[str, float] | None = None
    deflection: tuple[float, ...] | None = None

    def check(self) -> None:
        check_finite("q", self.q, JOINT_LIMIT_RAD)
        if (self.target_xyz is None) != (self.target_quat is None):
            raise RejectedMessageError("malformed", "target needs both target_xyz and target_quat")
        if self.target_xyz is not None:
            check_finite("target_xyz", self.target_xyz, 100.0, length=3)
            check_finite("target_quat", self.target_quat, 1.001, length=4)
        if self.deflection is not None:
            check_finite("deflection", self.deflection, 1.0, length=len(self.q))
        if self.temperatures is not None:
            if not isinstance(self.temperatures, dict):
                raise RejectedMessageError("malformed", "temperatures must map names to °C")
            check_finite("temperatures", tuple(self.temperatures.values()), 150.0)


@dataclass(frozen=True, kw_only=True)
class CompensationReply:
    """Predicted error at the command (m, rad), its interval and variances, the corrected
    command (rad), the iteration count and remaining residual (m) of that command, trust, the
    policy that decided the answer (``none`` when the solver landed, else one of
    :data:`POLICIES`), the largest joint motion of the answer from the command (rad) and the
    orientation residual of the answer (rad)."""

    SCHEMA: ClassVar[str] = "robocal.compensate.reply"
    model_version: int
    error: tuple[float, ...]
    lo: tuple[float, ...]
    hi: tuple[float, ...]
    level: float
    aleatoric: tuple[float, ...]
    epistemic: tuple[float, ...]
    q_corrected: tuple[float, ...]
    iterations: int
    residual_m: float
    trusted: bool
    reason: str = ""
    policy: str = "none"
    joint_motion_rad: float = 0.0
    residual_rad: float = 0.0

    def check(self) -> None:
        return None


def request_features(model: ErrorModel, req: CompensationRequest, q: np.ndarray) -> np.ndarray:
    """Raw features ``(1, F)`` of ``req`` at the command ``q`` (rad), through the learner's one
    builder: the request's deflection (zero without one) and temperatures (°C, by channel or
    column name); ``malformed`` when it lacks a temperature the model needs."""
    defl = np.zeros(len(q)) if req.deflection is None else np.asarray(req.deflection, dtype=float)
    try:
        return features(model.spec, q[None], defl[None], req.temperatures)
    except DatasetError as exc:
        raise RejectedMessageError("malformed", f"request: {exc}") from None


def controller_jacobian(robot: RobotModel, q: np.ndarray) -> np.ndarray:
    """Tool Jacobian ``(6, n)`` w.r.t. controller angles (J2/J3 coupling applied)."""
    J = robot.jacobian(q[None])[0]
    if robot.description.coupling == "j3_plus_j2":
        J = J.copy()
        J[:, 1] += J[:, 2]
    return J


def damped_step(J: np.ndarray, r: np.ndarray, damping: float, max_step: float) -> np.ndarray:
    """Damped least squares ``J^T (J J^T + d^2 I)^-1 r``, capped at ``max_step`` (rad): stays
    small near singular poses, where a plain pseudo-inverse would swing the wrist."""
    step = J.T @ np.linalg.solve(J @ J.T + damping**2 * np.eye(J.shape[0]), r)
    norm = float(np.abs(step).max())
    return step if norm <= max_step else step * (max_step / norm)


def compensate(
    model: ErrorModel,
    robot: RobotModel,
    req: CompensationRequest,
    cfg: CompensationConfig,
    model_version: int = 0,
) -> CompensationReply:
    """Predict the error at ``req.q`` and the command that lands on the target (pure)."""
    q0 = np.asarray(req.q, dtype=float)
    pred0 = model.predict(request_features(model, req, q0))
    residual_at = residual_function(model, robot, req)
    q, r, iterations = solve(residual_at, robot, q0, cfg, cfg.max_iterations, cfg.max_step_rad)
    residual = float(np.linalg.norm(r[:3]))
    lo, hi = pred0.interval(cfg.level)
    epistemic = pred0.epistemic()[0]
    worst_mm = float(np.sqrt(epistemic[:3].max())) * 1000.0
    trusted = worst_mm <= cfg.epistemic_limit_mm
    return CompensationReply(
        model_version=model_version,
        error=tuple(pred0.mean[0].tolist()),
        lo=tuple(lo[0].tolist()),
        hi=tuple(hi[0].tolist()),
        level=cfg.level,
        aleatoric=tuple(pred0.aleatoric()[0].tolist()),
        epistemic=tuple(epistemic.tolist()),
        q_corrected=tuple(q.tolist()),
        iterations=iterations,
        residual_m=residual,
        trusted=trusted,
        reason=""
        if trusted
        else f"epistemic std {worst_mm:.3f} mm > limit {cfg.epistemic_limit_mm} mm",
        joint_motion_rad=float(np.abs(q - q0).max()),
        residual_rad=float(np.linalg.norm(r[3:])),
    )


def _target(robot: RobotModel, req: CompensationRequest) -> np.ndarray:
    """The pose (4, 4) the request asks to land on: its target, else the command's nominal."""
    if req.target_xyz is None:
        return robot.fk(np.asarray(req.q, dtype=float)[None])[0]
    return transform_from_xyz_quat(np.asarray(req.target_xyz), np.asarray(req.target_quat))[0]


def residual_function(
    model: ErrorModel, robot: RobotModel, req: CompensationRequest
) -> Callable[[np.ndarray], np.ndarray]:
    """``q -> pose_error(target, predicted pose at q)`` (6,) m, rad, for the request's target
    and features."""
    target = _target(robot, req)

    def residual_at(q: np.ndarray) -> np.ndarray:
        e = model.predict(request_features(model, req, q)).mean
        return pose_error(target[None], apply_error(robot.fk(q[None]), e))[0]

    return residual_at


def solve(
    residual_at: Callable[[np.ndarray], np.ndarray],
    robot: RobotModel,
    q_start: np.ndarray,
    cfg: CompensationConfig,
    max_iterations: int,
    max_step: float,
    box: tuple[np.ndarray, np.ndarray] | None = None,
    rotation_weight: float = 1.0,
) -> tuple[np.ndarray, np.ndarray, int]:
    """Levenberg-Marquardt from ``q_start`` (rad): the command, its residual (6,) and the
    iterations used; ``box`` (low, high rad) bounds every iterate (best effort's motion limit);
    ``rotation_weight`` weighs the orientation rows against the position rows (m per rad)."""
    w = np.array([1.0, 1.0, 1.0, *[rotation_weight] * 3])
    q = np.asarray(q_start, dtype=float).copy()
    r = residual_at(q)
    damping, iterations = cfg.damping, 0
    for iterations in range(1, max_iterations + 1):  # noqa: B007
        if np.linalg.norm(r[:3]) < cfg.tolerance_m and np.linalg.norm(w[3:] * r[3:]) < (
            cfg.tolerance_m
        ):
            break
        J = w[:, None] * controller_jacobian(robot, q)
        for _ in range(8):  # Levenberg-Marquardt: raise the damping until the step helps
            q_try = q + damped_step(J, w * r, damping, max_step)
            if box is not None:
                q_try = np.clip(q_try, *box)
            r_try = residual_at(q_try)
            if np.linalg.norm(w * r_try) < np.linalg.norm(w * r):
                q, r, damping = q_try, r_try, max(damping / 10.0, 1e-12)
                break
            damping *= 10.0
        else:
            break  # no step reduces the residual: the best reachable command
    return q, r, iterations


def best_effort(
    model: ErrorModel,
    robot: RobotModel,
    req: CompensationRequest,
    cfg: CompensationConfig,
    reply: CompensationReply,
) -> CompensationReply:
    """``reply`` solved again from the command or its partial correction, position first
    (orientation rows weighed by ``best_effort_rotation_weight``), with larger steps
    (``best_effort_step_rad``, ``best_effort_iterations``) inside the joint limits and within
    ``joint_motion_limit_rad`` of the command on every joint; residuals and motion updated."""
    q0 = np.asarray(req.q, dtype=float)
    limits = robot.description.limits_rad
    low = np.maximum(q0 - cfg.joint_motion_limit_rad, limits[:, 0])
    high = np.minimum(q0 + cfg.joint_motion_limit_rad, limits[:, 1])
    residual_at = residual_function(model, robot, req)
    w = np.array([1.0, 1.0, 1.0, *[cfg.best_effort_rotation_weight] * 3])
    # start from the command or the partial correction, whichever is closer once in the box
    starts = (q0, np.clip(np.asarray(reply.q_corrected, dtype=float), low, high))
    start = min(starts, key=lambda q: float(np.linalg.norm(w * residual_at(q))))
    q, r, iterations = solve(
        residual_at,
        robot,
        start,
        cfg,
        cfg.best_effort_iterations,
        cfg.best_effort_step_rad,
        (low, high),
        cfg.best_effort_rotation_weight,
    )
    return replace(
        reply,
        q_corrected=tuple(q.tolist()),
        iterations=reply.iterations + iterations,
        residual_m=float(np.linalg.norm(r[:3])),
        joint_motion_rad=float(np.abs(q - q0).max()),
        residual_rad=float(np.linalg.norm(r[3:])),
    )
