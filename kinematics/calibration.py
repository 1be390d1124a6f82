"""Classical geometric calibration: DH-Hayati deviations with ``T_W_0`` and ``T_6_S``.

The deviations of every DH-Hayati parameter (a, d, alpha, beta, offset per joint) and small
corrections of the base and tool frames are identified by nonlinear least squares
(:func:`scipy.optimize.least_squares`) from measured probe poses. Only identifiable parameters
are estimated: QR with column pivoting of the column-scaled identification Jacobian at the
nominal drops those whose columns are (near) linear combinations of others (``d1`` with the
base ``z``, offsets with base/tool rotations, ...). The same least-squares machinery
(:func:`fit_effects`) refits any list of effects; the discrepancy workflow uses it.

>>> from kinematics.description import load_description
>>> names = calibration_parameter_names(load_description("ur10"))
>>> len(names), names[0], names[-1]
(42, 'a1_m', 'tool_rz_rad')
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np
from scipy.linalg import qr
from threadpoolctl import threadpool_limits

from kinematics.dataset import Dataset
from kinematics.description import RobotDescription
from kinematics.effects._base import (
    DH_FIELDS,
    Conditions,
    Effect,
    Perturbation,
    Restricted,
    frame_correction,
)
from kinematics.error_stats import ErrorStats
from kinematics.errors import ConfigError, IdentifiabilityError, RobocalError
from kinematics.identification.conditions import (
    Observations,
    cell_description,
    observations_from_dataset,
)
from kinematics.identification.fitting import (
    Block,
    FitResult,
    fit_effects,
    jacobian,
    tool_motion_rms,
)
from kinematics.model import RobotModel
from kinematics.transforms import ARCMIN_PER_RAD, rotation_angle

_DH_UNITS = ("m", "m", "rad", "rad", "rad")
#: Tool motion (mm, RMS over the joint limits) of one standard deviation of the prior on each
#: deviation (:func:`prior_std`). A calibration of poses from one region fits deviations that
#: cancel there and add up elsewhere: on UR10 Series A's first 200 points least squares is
#: 9.6 mm off on the rest of the series, 0.8 mm under this prior; spread data move by 3 um at
#: most (UR10 A and B, random arms). UR10 A's and B's least-squares deviations are 0.1-1.5 mm
#: in these units (``bench/calibration_prior.py``; BENCHMARKS.md, "A prior on the deviations").
PRIOR_MM = 0.3
#: Joint configurations (uniform within the limits, seeded) :func:`prior_std` averages over.
_PRIOR_SAMPLES = 256
#: Effects that move frames, which a prior towards none would hold wrongly.
_FRAME_EFFECTS = ("base_frame", "tool_frame", "tracker_drift")
FRAME_FIELDS = ("x_m", "y_m", "z_m", "rx_rad", "ry_rad", "rz_rad")


@dataclass(frozen=True, kw_only=True)
class CalibrationConfig:
    """Settings of the geometric calibration.

    ``rank_rtol``: a parameter is dropped when its pivoted-QR diagonal, relative to the
    largest, is below this (unit-norm columns). ``min_points_per_parameter``: the least number
    of measured points per identified parameter. ``min_joint_range_deg``: every joint must move
    at least this much, or its parameters would be folded into others only for that angle.
    ``prior_mm``: the DH deviations (and the effects ``robocal gap`` adds) are a MAP estimate
    under a Gaussian prior, each one's standard deviation what moves the tool by this much (RMS
    over the joint limits, :func:`prior_std`); None: least squares. Frames are always free.
    """

    rank_rtol: float = 1e-4
    prior_mm: float | None = PRIOR_MM
    min_points_per_parameter: float = 1.0
    min_joint_range_deg: float = 1.0
    max_nfev: int = 50

    def __post_init__(self) -> None:
        if not 0 < self.rank_rtol < 1:
            raise ConfigError(f"calibration.rank_rtol must be in (0, 1), got {self.rank_rtol}")
        if self.min_points_per_parameter <= 0:
            raise ConfigError(
                "calibration.min_points_per_parameter must be > 0, got "
                f"{self.min_points_per_parameter}"
            )
        if self.min_joint_range_deg < 0:
            raise ConfigError(
                f"calibration.min_joint_range_deg must be >= 0, got {self.min_joint_range_deg}"
            )
        if self.prior_mm is not None and not self.prior_mm > 0:
            raise ConfigError(f"calibration.prior_mm must be > 0, got {self.prior_mm}")
        if self.max_nfev < 1:
            raise ConfigError(f"calibration.max_nfev must be >= 1, got {self.max_nfev}")


def calibration_parameter_names(desc: RobotDescription) -> tuple[str, ...]:
    """All candidate parameters: DH deviations per joint, then base and tool corrections."""
    dh = [
        f"{field}{i}_{unit}"
        for i in range(1, desc.n_joints + 1)
        for field, unit in zip(DH_FIELDS, _DH_UNITS, strict=True)
    ]
    return (*dh, *(f"base_{f}" for f in FRAME_FIELDS), *(f"tool_{f}" for f in FRAME_FIELDS))


class _DhAndFrames(Effect):
    """Every DH deviation plus base/tool corrections: the classical calibration parameters."""

    name = "geometric_frames"

    def __init__(self, desc: RobotDescription) -> None:
        self._names = calibration_parameter_names(desc)

    def parameter_names(self, desc: RobotDescription) -> tuple[str, ...]:
        return self._names

    def perturbation(self, model: RobotModel, params: np.ndarray, cond: Conditions) -> Perturbation:
        n = model.description.n_joints
        x = np.asarray(params, dtype=float)
        out = Perturbation.zero(cond.n_points, n)
        out.ddh[:] = x[: 5 * n].reshape(n, 5)
        out.base[:] = frame_correction(x[5 * n : 5 * n + 3], x[5 * n + 3 : 5 * n + 6])
        out.tool[:] = frame_correction(x[5 * n + 6 : 5 * n + 9], x[5 * n + 9 :])
        return out


class GeometricFrames(Restricted):
    """DH deviations plus base/tool corrections, restricted to the ``free`` parameter indices."""

    def __init__(self, desc: RobotDescription, free: tuple[int, ...] | None = None) -> None:
        super().__init__(_DhAndFrames(desc), desc, free)


class ResidualStats(ErrorStats):
    """Position (mm) and orientation (arcmin) residual statistics of ``n`` points."""

    #: The keys of ``robocal calibrate --json``'s and ``robocal gap --json``'s residuals.
    KEYS = ("n", "mean_mm", "rms_mm", "std_mm", "max_mm", "mean_arcmin", "max_arcmin")


def residual_stats(T_measured: np.ndarray, T_predicted: np.ndarray) -> ResidualStats:
    """Statistics of measured vs predicted poses ``(N, 4, 4)``."""
    d = np.linalg.norm(T_measured[:, :3, 3] - T_predicted[:, :3, 3], axis=1) * 1e3
    R = np.einsum("nij,nkj->nik", T_measured[:, :3, :3], T_predicted[:, :3, :3])
    ang = ARCMIN_PER_RAD * rotation_angle(R)
    return ResidualStats.of(d, ang)


@dataclass(frozen=True, kw_only=True)
class Identifiability:
    """Which parameters the poses determine: kept/dropped names, condition number."""

    kept: tuple[str, ...]
    dropped: tuple[str, ...]
    kept_index: tuple[int, ...]
    condition_number: float


def identifiable(J: np.ndarray, names: tuple[str, ...], rank_rtol: float) -> Identifiability:
    """Select independent columns of ``J`` by QR with column pivoting on unit-norm columns.

    >>> J = np.array([[1.0, 2.0, 0.0], [0.0, 0.0, 1.0], [1.0, 2.0, 1.0]])
    >>> identifiable(J, ("a", "b", "c"), 1e-6).dropped
    ('b',)
    """
    norms = np.linalg.norm(J, axis=0)
    live = np.flatnonzero(norms > 0)
    _, R, piv = qr(J[:, live] / norms[live], mode="economic", pivoting=True)
    diag = np.abs(np.diag(R))
    rank = int(np.sum(diag > rank_rtol * diag[0])) if diag.size else 0
    kept_idx = tuple(sorted(int(live[p]) for p in piv[:rank]))
    sv = np.linalg.svd(J[:, kept_idx] / norms[list(kept_idx)], compute_uv=False)
    return Identifiability(
        kept=tuple(names[i] for i in kept_idx),
        dropped=tuple(n for i, n in enumerate(names) if i not in kept_idx),
        kept_index=kept_idx,
        condition_number=float(sv[0] / sv[-1]) if sv.size else float("inf"),
    )


@dataclass(frozen=True, kw_only=True)
class CalibrationResult:
    """A calibrated description (tool = identified ``T_6_S``), ``T_W_0`` and the evidence;
    ``prior_mm`` the prior it was fitted under (None: least squares)."""

    description: RobotDescription
    T_W_0: np.ndarray
    identifiability: Identifiability
    values: dict[str, float]
    std: dict[str, float]
    residual: ResidualStats
    rotation_weight_m: float
    rss: float
    dof: int
    prior_mm: float | None = None

    def to_dict(self) -> dict:
        """A JSON-ready summary (parameters in SI, residuals in mm / arcmin)."""
        return {
            "kept": list(self.identifiability.kept),
            "dropped": list(self.identifiability.dropped),
            "condition_number": self.identifiability.condition_number,
            "parameters": self.values,
            "prior_mm": self.prior_mm,
            "std": self.std,
            "residual": self.residual.to_dict(),
            "T_W_0": self.T_W_0.tolist(),
        }


def rest_observations(model: RobotModel, q: np.ndarray) -> Observations:
    """Poses ``q`` (N, n; rad) at rest (no load, no temperature, t = 0) as the nominal model
    measures them in its base frame: what a Jacobian at the nominal needs before any point
    is measured."""
    cond = Conditions(q=q, t=np.zeros(len(q)))
    return Observations(cond=cond, T_measured=model.fk(q), T_W_0=np.eye(4))


def prior_std(model: RobotModel, effect: Effect, prior_mm: float) -> np.ndarray:
    """Per parameter of ``effect``, the standard deviation (its unit) of a Gaussian prior that
    holds it to what moves the tool by ``prior_mm`` RMS over the robot's joint limits at rest
    (rotations on a 1 m lever; no load, no temperature, t = 0): poses of one region cannot then
    fit deviations that cancel there and grow elsewhere. Parameters nothing moves at rest, and
    frame corrections (the tracker and the tool may sit anywhere), get none (infinite)."""
    n = len(effect.parameter_names(model.description))
    std = np.full(n, np.inf)
    if effect.name in _FRAME_EFFECTS:
        return std
    desc = model.description
    lower, upper = desc.limits_rad.T
    q = np.random.default_rng(0).uniform(lower, upper, (_PRIOR_SAMPLES, desc.n_joints))
    obs = rest_observations(model, q)
    try:
        J = jacobian(model, obs, [(effect, np.zeros(n))], 1.0)
    except RobocalError:  # needs conditions that rest does not give (temperatures, approach)
        return std
    moved = tool_motion_rms(J)
    held = moved > 0
    if isinstance(effect, GeometricFrames):
        held &= np.asarray(effect.free) < len(DH_FIELDS) * desc.n_joints
    std[held] = prior_mm * 1e-3 / moved[held]
    return std


def fit_under_prior(
    model: RobotModel, obs: Observations, blocks: list[Block], config: CalibrationConfig
) -> FitResult:
    """``blocks`` fitted to ``obs`` under :func:`prior_std`'s prior on every block's parameters
    at ``config.prior_mm`` (none where it is None): calibration, the gap workflow's fits and a
    base fitted again all hold their deviations this way."""
    prior = None
    if blocks and config.prior_mm is not None:
        prior = np.concatenate([prior_std(model, effect, config.prior_mm) for effect, _ in blocks])
    return fit_effects(model, obs, blocks, max_nfev=config.max_nfev, prior_std=prior)


def calibrate(
    desc: RobotDescription, ds: Dataset, config: CalibrationConfig | None = None
) -> CalibrationResult:
    """Identify the identifiable DH deviations and frame corrections from ``ds``.

    Raises :class:`IdentifiabilityError` when there are too few points for the parameters
    the poses excite. Linear algebra runs single-threaded (thin matrices; threaded BLAS on a
    busy machine is many times slower).
    """
    with threadpool_limits(limits=1, user_api="blas"):
        return _calibrate(desc, ds, config or CalibrationConfig())


def identify(model: RobotModel, obs: Observations, config: CalibrationConfig) -> Identifiability:
    """The identifiable calibration parameters at the nominal, after checking that every joint
    moves and that there are enough points; else :class:`IdentifiabilityError`."""
    desc = model.description
    span = np.rad2deg(np.ptp(np.asarray(obs.cond.q), axis=0)) if obs.n_points else np.zeros(1)
    still = np.flatnonzero(span < config.min_joint_range_deg)
    if still.size:
        raise IdentifiabilityError(
            f"joint {still[0] + 1} moves over {span[still[0]]:.3g} deg in the data, calibration "
            f"needs at least {config.min_joint_range_deg} deg on every joint"
        )
    full = GeometricFrames(desc)
    names = full.parameter_names(desc)
    J0 = jacobian(model, obs, [(full, np.zeros(len(names)))], 1.0)
    ident = identifiable(J0, names, config.rank_rtol)
    need = int(np.ceil(config.min_points_per_parameter * len(ident.kept)))
    if obs.n_points < max(need, 2):
        raise IdentifiabilityError(
            f"calibration needs at least {need} points for {len(ident.kept)} identifiable "
            f"parameters, got {obs.n_points}"
        )
    return ident


def _calibrate(desc: RobotDescription, ds: Dataset, config: CalibrationConfig) -> CalibrationResult:
    desc = cell_description(desc, ds)
    model = RobotModel(desc)
    obs = observations_from_dataset(ds, desc)
    ident = identify(model, obs, config)
    effect = GeometricFrames(desc, ident.kept_index)
    fit = fit_under_prior(model, obs, [(effect, np.zeros(len(ident.kept)))], config)
    values = effect.full(fit.params[0])
    calibrated, T_W_0 = apply_calibration(desc, obs.T_W_0, values)
    predicted = T_W_0[None] @ RobotModel(calibrated).fk(obs.cond.q)
    return CalibrationResult(
        description=calibrated,
        T_W_0=T_W_0,
        identifiability=ident,
        values=dict(zip(ident.kept, map(float, fit.params[0]), strict=True)),
        std=dict(zip(ident.kept, map(float, fit.std[0]), strict=True)),
        residual=residual_stats(obs.T_measured, predicted),
        rotation_weight_m=fit.rotation_weight_m,
        rss=fit.rss,
        dof=fit.dof,
        prior_mm=config.prior_mm,
    )


def apply_calibration(
    desc: RobotDescription, T_W_0: np.ndarray, values: np.ndarray
) -> tuple[RobotDescription, np.ndarray]:
    """Fold full calibration parameters into a description and a base frame ``T_W_0``."""
    n = desc.n_joints
    dh = values[: 5 * n].reshape(n, 5)
    joints = tuple(
        replace(
            j,
            a_m=float(j.a_m + dh[i, 0]),
            d_m=float(j.d_m + dh[i, 1]),
            alpha_deg=j.alpha_deg + float(np.rad2deg(dh[i, 2])),
            beta_deg=j.beta_deg + float(np.rad2deg(dh[i, 3])),
            offset_deg=j.offset_deg + float(np.rad2deg(dh[i, 4])),
        )
        for i, j in enumerate(desc.joints)
    )
    tool = desc.tool @ frame_correction(values[5 * n + 6 : 5 * n + 9], values[5 * n + 9 :])
    base = np.asarray(T_W_0, dtype=float) @ frame_correction(
        values[5 * n : 5 * n + 3], values[5 * n + 3 : 5 * n + 6]
    )
    return replace(desc, joints=joints, tool=tool), base


__all__ = [
    "CalibrationConfig",
    "CalibrationResult",
    "GeometricFrames",
    "Identifiability",
    "ResidualStats",
    "apply_calibration",
    "fit_under_prior",
    "PRIOR_MM",
    "calibrate",
    "calibration_parameter_names",
    "prior_std",
    "identifiable",
    "identify",
    "residual_stats",
]
