"""Robot-world / hand-eye calibration ``AX = ZB``: the tracker frame and the probe on the flange.

The measurement cell ties frames by ``T_W_S = T_W_0 · T_0_6(q) · T_6_S`` (DESIGN.md). Given
measured probe poses ``T_W_S`` and flange poses ``T_0_6`` (nominal FK of the joint angles),
:func:`fit_frames` identifies ``T_W_0`` and ``T_6_S``: a closed-form start (Shah's
Kronecker-product solution, with ``A = T_0_6``, ``X = T_6_S``, ``Z = T_0_W``, ``B = T_W_S``)
refined by nonlinear least squares over SE(3). Position-only data (a 3-D tracker without
orientation) is supported through :func:`fit_frames_positions`.

>>> import numpy as np
>>> from kinematics.description import load_description
>>> from kinematics.model import RobotModel
>>> from kinematics.transforms import transform_from_xyz_rpy
>>> m = RobotModel(load_description("ur10"))
>>> q = np.random.default_rng(0).uniform(-2.0, 2.0, (20, 6))
>>> T_W_0 = transform_from_xyz_rpy([2.0, -1.0, 0.3], [0.1, -0.2, 2.5])
>>> T_6_S = transform_from_xyz_rpy([0.0, 0.01, 0.109], [0.0, 0.0, 1.57])
>>> fit = identify_frames(m, q, T_W_0 @ m.fk(q, frame="flange") @ T_6_S)
>>> bool(np.allclose(fit.T_W_0, T_W_0, atol=1e-9)), fit.summary().max_mm < 1e-6
(True, True)
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np
from scipy.optimize import least_squares
from scipy.spatial.transform import Rotation

from kinematics.dataset import Dataset
from kinematics.description import RobotDescription
from kinematics.error_stats import ErrorStats
from kinematics.errors import ConfigError, DatasetError, IdentifiabilityError
from kinematics.model import RobotModel
from kinematics.outliers import gross_outliers
from kinematics.transforms import (
    ARCMIN_PER_RAD,
    invert,
    rotation_angle,
    transform,
    vee_skew,
)

__all__ = [
    "FitSummary",
    "FrameFit",
    "FrameFitConfig",
    "closed_form_axzb",
    "fit_frames",
    "fit_frames_positions",
    "fit_frames_screened",
    "identify_frames",
    "reframed",
    "tracker_to_base",
]


@dataclass(frozen=True, kw_only=True)
class FrameFitConfig:
    """Settings of the nonlinear refinement.

    ``orientation_weight_m`` turns an orientation residual (rad) into metres: with 0.5 m/rad,
    1 mrad counts like 0.5 mm (about the ratio of the T-Mac's position and angle noise).
    ``loss`` is a :func:`scipy.optimize.least_squares` loss (``"soft_l1"`` resists outliers),
    ``f_scale_m`` its inlier scale.
    """

    orientation_weight_m: float = 0.5
    loss: str = "linear"
    f_scale_m: float = 1e-3
    max_nfev: int = 200

    def __post_init__(self) -> None:
        if not self.orientation_weight_m > 0:
            raise ConfigError(f"orientation_weight_m must be > 0, got {self.orientation_weight_m}")
        if self.loss not in ("linear", "soft_l1", "huber", "cauchy", "arctan"):
            raise ConfigError(f"loss must be a least_squares loss, got {self.loss!r}")
        if not self.f_scale_m > 0:
            raise ConfigError(f"f_scale_m must be > 0, got {self.f_scale_m}")
        if self.max_nfev < 1:
            raise ConfigError(f"max_nfev must be >= 1, got {self.max_nfev}")


class FitSummary(ErrorStats):
    """Residual statistics of a frame fit (mm, arcmin; arcmin NaN for position-only fits)."""

    #: The keys of an imported dataset's ``frame_fit`` metadata.
    KEYS = ("n", "mean_mm", "rms_mm", "max_mm", "mean_arcmin", "rms_arcmin", "max_arcmin")


@dataclass(frozen=True, kw_only=True)
class FrameFit:
    """Identified cell frames and the per-point residuals that remain.

    ``residual_mm`` is the position residual norm per point; ``residual_arcmin`` the angle of
    the orientation residual (None for position-only fits).
    """

    T_W_0: np.ndarray
    T_6_S: np.ndarray
    residual_mm: np.ndarray
    residual_arcmin: np.ndarray | None
    nfev: int
    success: bool

    def summary(self) -> FitSummary:
        return FitSummary.of(self.residual_mm, self.residual_arcmin)


def tracker_to_base(T_W_S: np.ndarray, T_W_0: np.ndarray) -> np.ndarray:
    """Probe poses in the robot base, ``T_0_S = T_W_0^-1 · T_W_S``, ``(N, 4, 4)``."""
    return invert(np.asarray(T_W_0, dtype=float))[None] @ np.asarray(T_W_S, dtype=float)


def _project_so3(M: np.ndarray) -> np.ndarray:
    """The rotation nearest to ``M`` (Frobenius), via SVD."""
    U, _, Vt = np.linalg.svd(M)
    return U @ np.diag([1.0, 1.0, np.linalg.det(U @ Vt)]) @ Vt


def _check_poses(T: np.ndarray, name: str) -> np.ndarray:
    T = np.asarray(T, dtype=float)
    if T.ndim != 3 or T.shape[1:] != (4, 4):
        raise IdentifiabilityError(f"{name} must have shape (N, 4, 4), got {T.shape}")
    if not np.all(np.isfinite(T)):
        raise IdentifiabilityError(f"{name} contains non-finite values")
    return T


def closed_form_axzb(T_W_S: np.ndarray, T_0_6: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Shah's closed form: ``(T_W_0, T_6_S)`` from at least 3 pose pairs, no start needed.

    Rotations come from the null vector of the stacked Kronecker system
    ``(I ⊗ R_A) vec(R_X) - (R_B^T ⊗ I) vec(R_Z) = 0``, translations from linear least squares
    of ``R_A t_X - t_Z = R_Z t_B - t_A``.
    """
    B = _check_poses(T_W_S, "T_W_S")
    A = _check_poses(T_0_6, "T_0_6")
    if len(A) != len(B) or len(A) < 3:
        raise IdentifiabilityError(f"need >= 3 matching pose pairs, got {len(A)} and {len(B)}")
    eye = np.eye(3)
    RA, RB = A[:, :3, :3], B[:, :3, :3]
    # Column-major vec: vec(R_A R_X) = (I ⊗ R_A) vec(R_X); vec(R_Z R_B) = (R_B^T ⊗ I) vec(R_Z).
    K = np.concatenate(
        [
            np.einsum("ab,nij->naibj", eye, RA).reshape(-1, 9, 9),
            -np.einsum("nba,ij->naibj", RB, eye).reshape(-1, 9, 9),
        ],
        axis=2,
    )
    evals, evecs = np.linalg.eigh(np.einsum("nij,nik->jk", K, K))
    if evals[1] < 1e-12 * evals[-1]:
        raise IdentifiabilityError(
            "the rotations do not determine the frames (poses too similar); vary the orientation"
        )
    v = evecs[:, 0]
    RX_raw = v[:9].reshape(3, 3, order="F")
    RZ_raw = v[9:].reshape(3, 3, order="F")
    sign = np.sign(np.linalg.det(RX_raw)) or 1.0
    RX = _project_so3(sign * RX_raw)
    RZ = _project_so3(sign * RZ_raw)
    # R_A t_X - t_Z = R_Z t_B - t_A, stacked over points.
    M = np.concatenate([np.concatenate([a[:3, :3], -eye], axis=1) for a in A])
    rhs = np.concatenate([RZ @ b[:3, 3] - a[:3, 3] for a, b in zip(A, B, strict=True)])
    sol, *_ = np.linalg.lstsq(M, rhs, rcond=None)
    T_6_S = transform(RX, sol[:3])
    T_0_W = transform(RZ, sol[3:])
    return invert(T_0_W), T_6_S


def _perturb(T: np.ndarray, x: np.ndarray) -> np.ndarray:
    """``T`` moved by a rotation vector ``x[:3]`` (rad, left) and a translation ``x[3:]`` (m)."""
    out = T.copy()
    out[:3, :3] = Rotation.from_rotvec(x[:3]).as_matrix() @ T[:3, :3]
    out[:3, 3] = T[:3, 3] + x[3:]
    return out


def _refine(residual, x_size: int, config: FrameFitConfig):
    """Trust-region least squares over frame corrections, starting at zero."""
    return least_squares(
        residual,
        np.zeros(x_size),
        method="trf",
        x_scale="jac",
        loss=config.loss,
        f_scale=config.f_scale_m,
        max_nfev=config.max_nfev,
    )


def fit_frames(
    T_W_S: np.ndarray,
    T_0_6: np.ndarray,
    *,
    T_W_0_init: np.ndarray | None = None,
    T_6_S_init: np.ndarray | None = None,
    config: FrameFitConfig | None = None,
) -> FrameFit:
    """Identify ``T_W_0`` and ``T_6_S`` from measured 6-D probe poses and flange poses.

    The refinement starts from whichever is closer to the data: the closed form of
    :func:`closed_form_axzb` or the given start (a missing one of the two frames is averaged
    from the data). It minimises position (m) and weighted orientation residuals
    ``vec(R_m R_c^T)`` (DESIGN's label, the angle for small errors; a start within 90° of the
    answer is needed, which the choice of start provides).
    """
    config = config or FrameFitConfig()
    B = _check_poses(T_W_S, "T_W_S")
    A = _check_poses(T_0_6, "T_0_6")
    if len(A) != len(B) or len(A) < 3:
        raise IdentifiabilityError(f"need >= 3 matching pose pairs, got {len(A)} and {len(B)}")
    w = config.orientation_weight_m
    starts = []
    if T_W_0_init is not None or T_6_S_init is not None:
        starts.append(_complete_start(B, A, T_W_0_init, T_6_S_init))
    try:
        starts.append(closed_form_axzb(B, A))
    except IdentifiabilityError:
        if not starts:
            raise
    W0_init, S6_init = min(starts, key=lambda s: _cost(B, A, s[0], s[1], w))

    def frames(x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        return _perturb(W0_init, x[:6]), _perturb(S6_init, x[6:])

    def residual(x: np.ndarray) -> np.ndarray:
        W0, S6 = frames(x)
        P = W0[None] @ A @ S6[None]
        dp = P[:, :3, 3] - B[:, :3, 3]
        dR = vee_skew(B[:, :3, :3] @ np.swapaxes(P[:, :3, :3], 1, 2))
        return np.concatenate([dp, w * dR], axis=1).ravel()

    result = _refine(residual, 12, config)
    W0, S6 = frames(result.x)
    P = W0[None] @ A @ S6[None]
    dR = B[:, :3, :3] @ np.swapaxes(P[:, :3, :3], 1, 2)
    return FrameFit(
        T_W_0=W0,
        T_6_S=S6,
        residual_mm=1e3 * np.linalg.norm(P[:, :3, 3] - B[:, :3, 3], axis=1),
        residual_arcmin=ARCMIN_PER_RAD * Rotation.from_matrix(dR).magnitude(),
        nfev=int(result.nfev),
        success=bool(result.success),
    )


def fit_frames_screened(
    T_W_S: np.ndarray,
    T_0_6: np.ndarray,
    *,
    T_W_0_init: np.ndarray | None = None,
    T_6_S_init: np.ndarray | None = None,
) -> tuple[FrameFit, np.ndarray]:
    """:func:`fit_frames` without the rows whose residual is a gross outlier
    (:func:`kinematics.outliers.gross_outliers` on position and angle residuals) under a
    ``soft_l1`` fit, which one such row cannot tilt: a lost beam 1 m off tilted UR10 Series B's
    least-squares frames enough to take its other rows from 1.03 to 1.45 mm. Returns the fit and
    the rows left out of it (empty: none, and the fit is :func:`fit_frames`' on every row)."""
    starts = {"T_W_0_init": T_W_0_init, "T_6_S_init": T_6_S_init}
    robust = fit_frames(T_W_S, T_0_6, **starts, config=FrameFitConfig(loss="soft_l1"))
    far = gross_outliers(
        np.column_stack([1e-3 * robust.residual_mm, robust.residual_arcmin / ARCMIN_PER_RAD])
    )
    keep = np.setdiff1d(np.arange(len(T_0_6)), far)
    return fit_frames(np.asarray(T_W_S)[keep], np.asarray(T_0_6)[keep], **starts), far


def identify_frames(
    model: RobotModel,
    q: np.ndarray,
    T_W_S: np.ndarray,
    *,
    T_W_0_init: np.ndarray | None = None,
    T_6_S_init: np.ndarray | None = None,
    config: FrameFitConfig | None = None,
) -> FrameFit:
    """:func:`fit_frames` with ``T_0_6`` from the nominal flange FK of joint angles ``q`` (rad)."""
    return fit_frames(
        T_W_S,
        model.fk(np.atleast_2d(q), frame="flange"),
        T_W_0_init=T_W_0_init,
        T_6_S_init=T_6_S_init,
        config=config,
    )


def reframed(ds: Dataset, desc: RobotDescription, rows: np.ndarray) -> Dataset:
    """``ds`` (tracker frame) with ``T_W_0`` and ``T_6_S`` identified from the points at
    ``rows`` alone (nominal kinematics of ``desc``, started from the frames ``ds`` has): what a
    new day knows of its frames from its first points. An importer fits them on every row, the
    points a test scores included, and a carry held near those frames leans on that."""
    if ds.meta.frame != "tracker":
        raise DatasetError(f"reframed needs tracker-frame poses, the dataset's are {ds.meta.frame}")
    rows = np.asarray(rows)
    fit = identify_frames(
        RobotModel(desc),
        ds.q()[rows],
        ds.measured_poses()[rows],
        T_W_0_init=ds.meta.T_W_0,
        T_6_S_init=ds.meta.T_6_S,
    )
    meta = replace(ds.meta, T_W_0=fit.T_W_0.tolist(), T_6_S=fit.T_6_S.tolist())
    return Dataset(ds.table, meta)


def _cost(B: np.ndarray, A: np.ndarray, W0: np.ndarray, S6: np.ndarray, w: float) -> float:
    """Sum of squared position (m) and weighted angle residuals of frames ``W0``, ``S6``."""
    P = W0[None] @ A @ S6[None]
    angle = rotation_angle(B[:, :3, :3] @ np.swapaxes(P[:, :3, :3], 1, 2))
    return float(np.sum((P[:, :3, 3] - B[:, :3, 3]) ** 2) + np.sum((w * angle) ** 2))


def _mean_pose(T: np.ndarray) -> np.ndarray:
    """The chordal mean rotation and the mean position of poses ``(N, 4, 4)``."""
    return transform(Rotation.from_matrix(T[:, :3, :3]).mean().as_matrix(), T[:, :3, 3].mean(0))


def _complete_start(
    B: np.ndarray, A: np.ndarray, W0: np.ndarray | None, S6: np.ndarray | None
) -> tuple[np.ndarray, np.ndarray]:
    """A full start ``(T_W_0, T_6_S)``; a missing frame is averaged from the data."""
    if W0 is None:
        S6 = np.asarray(S6, dtype=float)
        return _mean_pose(B @ invert(A @ S6[None])), S6
    W0 = np.asarray(W0, dtype=float)
    if S6 is None:
        return W0, _mean_pose(invert(W0[None] @ A) @ B)
    return W0, np.asarray(S6, dtype=float)


def _kabsch(src: np.ndarray, dst: np.ndarray) -> np.ndarray:
    """The rigid transform ``T`` minimising ``|T src - dst|`` over points ``(N, 3)``."""
    cs, cd = src.mean(axis=0), dst.mean(axis=0)
    R = _project_so3((dst - cd).T @ (src - cs))
    return transform(R, cd - R @ cs)


def fit_frames_positions(
    p_W_S: np.ndarray,
    T_0_6: np.ndarray,
    *,
    T_W_0_init: np.ndarray | None = None,
    p_6_S_init: np.ndarray | None = None,
    config: FrameFitConfig | None = None,
) -> FrameFit:
    """Identify ``T_W_0`` and the probe position on the flange from positions ``(N, 3)`` (m).

    The probe orientation is unobservable, so ``T_6_S`` carries the identity rotation. The
    start is a Kabsch fit of the flange-side probe points (``p_6_S_init``, default the flange
    origin) to the measured points.
    """
    config = config or FrameFitConfig()
    p = np.asarray(p_W_S, dtype=float)
    A = _check_poses(T_0_6, "T_0_6")
    if p.shape != (len(A), 3) or len(A) < 4:
        raise IdentifiabilityError(
            f"need >= 4 positions of shape (N, 3) matching T_0_6, got {p.shape} and {A.shape}"
        )
    if not np.all(np.isfinite(p)):
        raise IdentifiabilityError("p_W_S contains non-finite values")
    t_init = np.zeros(3) if p_6_S_init is None else np.asarray(p_6_S_init, dtype=float)
    if T_W_0_init is None:
        T_W_0_init = _kabsch(A[:, :3, :3] @ t_init + A[:, :3, 3], p)
    W0_init = np.asarray(T_W_0_init, dtype=float)

    def points(x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        W0 = _perturb(W0_init, x[:6])
        t = t_init + x[6:]
        return W0, (W0[:3, :3] @ (A[:, :3, :3] @ t + A[:, :3, 3]).T).T + W0[:3, 3]

    result = _refine(lambda x: (points(x)[1] - p).ravel(), 9, config)
    W0, pred = points(result.x)
    return FrameFit(
        T_W_0=W0,
        T_6_S=transform(np.eye(3), t_init + result.x[6:]),
        residual_mm=1e3 * np.linalg.norm(pred - p, axis=1),
        residual_arcmin=None,
        nfev=int(result.nfev),
        success=bool(result.success),
    )
