"""Compensation that refuses what it cannot do: every answer it cannot stand behind is
``trusted: false`` with a reason that starts with a code.

Codes (the reason is ``"<code>: <detail>"``): ``joint_limits`` (a commanded joint outside the
description's limits), ``quaternion`` (a target quaternion that is not a unit quaternion),
``unreachable`` (a target farther from the base than the arm reaches), ``solver`` (the solver
failed or gave non-finite numbers), ``residual`` (the corrected command misses the target by
more than ``max_residual_m``), ``corrected_limits`` (the corrected command leaves the limits),
``epistemic`` (the model has not seen data like this), ``envelope`` (a joint more than
``envelope_margin_deg`` past the angles the model was trained on, or a thermometer more than
``envelope_margin_k`` past the temperatures, :mod:`learner.envelope`: its base and network
extrapolate there and its intervals do not know it), ``unverified`` (a model carried into a
day whose frames moved or whose first points its intervals missed, and which its own held-out
points, spread over the workspace, have not yet checked:
:attr:`learner.model.ErrorModel.unverified`). A refusal before solving
answers with the uncorrected command and the error predicted there (zeros when even that fails).

A command the solver cannot land within ``max_residual_m`` (near a singular pose) is answered
by the configured policy (``CompensationConfig.policy``; the reply's ``policy`` names it and its
reason gives the solver residual in mm): ``refuse`` answers the uncorrected command,
``flag`` the partial correction, both ``residual: ...``; ``best_effort`` solves again, position
first, within the joint-motion limit and is trusted when the position lands (the orientation
it gave up is the reply's ``residual_rad``), else ``residual: ...`` with the command it reached.

>>> GuardConfig().max_residual_m
0.0001
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

import numpy as np

from kinematics.errors import ConfigError, RobocalError
from kinematics.model import RobotModel
from learner.envelope import why_outside
from learner.features import temperature_readings
from learner.model import ErrorModel
from stream.compensation import (
    CompensationConfig,
    CompensationReply,
    CompensationRequest,
    best_effort,
    compensate,
    request_features,
    residual_function,
)

QUATERNION_TOLERANCE = 1e-3


@dataclass(frozen=True, kw_only=True)
class GuardConfig:
    """The largest solver residual trusted (m) and the slack on joint limits (rad)."""

    max_residual_m: float = 1e-4
    limit_slack_rad: float = 1e-6

    def __post_init__(self) -> None:
        if not (math.isfinite(self.max_residual_m) and self.max_residual_m > 0):
            raise ConfigError(f"max_residual_m must be > 0, got {self.max_residual_m}")
        if not (math.isfinite(self.limit_slack_rad) and self.limit_slack_rad >= 0):
            raise ConfigError(f"limit_slack_rad must be >= 0, got {self.limit_slack_rad}")


def reach_m(robot: RobotModel) -> float:
    """An upper bound of the distance (m) from the base origin any tool pose can have."""
    desc = robot.description
    links = sum(math.hypot(j.a_m, j.d_m) for j in desc.joints)
    return links + float(np.linalg.norm(desc.tool[:3, 3]))


def outside_limits(robot: RobotModel, q: np.ndarray, slack: float) -> str:
    """The first joint outside the description's limits, as text; "" when all are inside."""
    lim = robot.description.limits_rad
    for i, (v, (lo, hi)) in enumerate(zip(q, lim, strict=True)):
        if not lo - slack <= v <= hi + slack:
            return (
                f"q{i + 1} = {math.degrees(v):.2f} deg outside "
                f"[{math.degrees(lo):.1f}, {math.degrees(hi):.1f}] deg"
            )
    return ""


def guarded_compensate(
    model: ErrorModel,
    robot: RobotModel,
    req: CompensationRequest,
    cfg: CompensationConfig,
    model_version: int = 0,
    guard: GuardConfig | None = None,
) -> CompensationReply:
    """:func:`~stream.compensation.compensate` behind the checks of the module doc."""
    guard = guard or GuardConfig()
    q = np.asarray(req.q, dtype=float)
    if why := outside_limits(robot, q, guard.limit_slack_rad):
        return _refused(model, robot, req, cfg, model_version, f"joint_limits: {why}")
    if req.target_quat is not None:
        norm = float(np.linalg.norm(req.target_quat))
        if not abs(norm - 1.0) <= QUATERNION_TOLERANCE:
            return _refused(
                model, robot, req, cfg, model_version, f"quaternion: norm {norm:.4g}, expected 1"
            )
        dist = float(np.linalg.norm(req.target_xyz))
        if dist > reach_m(robot):
            return _refused(
                model,
                robot,
                req,
                cfg,
                model_version,
                f"unreachable: target {dist:.3f} m from the base, reach {reach_m(robot):.3f} m",
            )
    try:
        reply = compensate(model, robot, req, cfg, model_version)
    except RobocalError:
        raise  # a bad request (e.g. a missing temperature): the asker gets the reason
    except Exception as exc:  # noqa: BLE001 - the solver failing is an answer, not a crash
        return _refused(model, robot, req, cfg, model_version, f"solver: {type(exc).__name__}")
    numbers = (*reply.error, *reply.lo, *reply.hi, *reply.q_corrected, reply.residual_m)
    if not all(math.isfinite(v) for v in numbers):
        return replace(reply, trusted=False, reason="solver: non-finite result")
    if reply.residual_m > guard.max_residual_m:
        reply = apply_policy(model, robot, req, cfg, reply, guard)
        if reply.policy != "best_effort" or reply.residual_m > guard.max_residual_m:
            return reply
    if why := outside_limits(robot, np.asarray(reply.q_corrected), guard.limit_slack_rad):
        return replace(reply, trusted=False, reason=f"corrected_limits: {why}")
    if not reply.trusted:
        return replace(reply, reason=f"epistemic: {reply.reason}")
    if model.envelope is not None:
        temps = {
            n: float(v[0])
            for n, v in temperature_readings(model.spec, request_features(model, req, q)).items()
        }
        if why := why_outside(
            model.envelope, q, temps, cfg.envelope_margin_deg, cfg.envelope_margin_k
        ):
            return replace(reply, trusted=False, reason=f"envelope: {why}")
    if model.unverified:
        return replace(reply, trusted=False, reason=f"unverified: {model.unverified}")
    return reply


def apply_policy(
    model: ErrorModel,
    robot: RobotModel,
    req: CompensationRequest,
    cfg: CompensationConfig,
    reply: CompensationReply,
    guard: GuardConfig,
) -> CompensationReply:
    """The answer to a command the solver left ``reply.residual_m`` short of its target, by
    ``cfg.policy`` (module doc); trusted only when best effort lands within
    ``guard.max_residual_m`` (and the model was trusted there)."""
    limit_mm, solver_mm = guard.max_residual_m * 1e3, reply.residual_m * 1e3
    if cfg.policy == "refuse":
        out = _refused(
            model,
            robot,
            req,
            cfg,
            reply.model_version,
            f"residual: solver {solver_mm:.3f} mm > {limit_mm:.3f} mm, policy refuse: "
            "uncorrected command",
        )
        miss = residual_function(model, robot, req)(np.asarray(req.q, dtype=float))
        return replace(
            out,
            policy="refuse",
            residual_m=float(np.linalg.norm(miss[:3])),
            residual_rad=float(np.linalg.norm(miss[3:])),
        )
    if cfg.policy == "flag":
        return replace(
            reply,
            trusted=False,
            policy="flag",
            reason=f"residual: solver {solver_mm:.3f} mm > {limit_mm:.3f} mm, policy flag: "
            f"partial correction ({reply.joint_motion_rad:.3f} rad joint motion)",
        )
    out = replace(best_effort(model, robot, req, cfg, reply), policy="best_effort")
    if out.residual_m <= guard.max_residual_m:
        return out
    return replace(
        out,
        trusted=False,
        reason=f"residual: {out.residual_m * 1e3:.3f} mm > {limit_mm:.3f} mm after best effort "
        f"within {cfg.joint_motion_limit_rad:g} rad (solver {solver_mm:.3f} mm before)",
    )


def _refused(
    model: ErrorModel,
    robot: RobotModel,
    req: CompensationRequest,
    cfg: CompensationConfig,
    model_version: int,
    reason: str,
) -> CompensationReply:
    """An untrusted answer: the uncorrected command and the error predicted there."""
    n = len(req.q)
    zeros = (0.0,) * 6
    error, lo, hi, ale, epi = zeros, zeros, zeros, zeros, zeros
    try:
        pred = model.predict(request_features(model, req, np.asarray(req.q, dtype=float)))
        lo_, hi_ = pred.interval(cfg.level)
        error, lo, hi = (tuple(float(v) for v in a[0]) for a in (pred.mean, lo_, hi_))
        ale = tuple(float(v) for v in pred.aleatoric()[0])
        epi = tuple(float(v) for v in pred.epistemic()[0])
        if not all(math.isfinite(v) for v in (*error, *lo, *hi, *ale, *epi)):
            raise ValueError("non-finite prediction")
    except Exception:  # noqa: BLE001 - the refusal stands without a prediction
        error, lo, hi, ale, epi = zeros, zeros, zeros, zeros, zeros
    return CompensationReply(
        model_version=model_version,
        error=error,
        lo=lo,
        hi=hi,
        level=cfg.level,
        aleatoric=ale,
        epistemic=epi,
        q_corrected=tuple(float(v) for v in req.q[:n]),
        iterations=0,
        residual_m=0.0,
        trusted=False,
        reason=reason,
    )
