"""Accuracy and honesty of a model on labelled data, in human units (mm, arcmin, %).

Position error is the norm of the position residual (mm); orientation error the norm of the
rotation residual ``vec`` (≈ angle, arcmin). Coverage counts position components inside the
Student-t interval; NLL is the mean predictive NLL of position components with labels in mm.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from kinematics.error_stats import ErrorStats
from kinematics.transforms import ARCMIN_PER_RAD
from learner.envelope import MARGIN_DEG, MARGIN_K, outside
from learner.evidential import Evidential
from learner.features import temperature_readings
from learner.model import ErrorModel

LEVELS = (0.68, 0.90, 0.95)


@dataclass(frozen=True, kw_only=True)
class AccuracyReport(ErrorStats):
    """Residual statistics after compensation and the interval calibration."""

    uncalibrated_mean_mm: float
    improvement_pct: float
    coverage_68: float
    coverage_90: float
    coverage_95: float
    interval_width_90_mm: float
    nll: float

    #: The keys of ``robocal train/continual/evaluate --json`` and of a snapshot's metrics.
    KEYS = (
        "n",
        "mean_mm",
        "std_mm",
        "max_mm",
        "p95_mm",
        "mean_arcmin",
        "uncalibrated_mean_mm",
        "improvement_pct",
        "coverage_68",
        "coverage_90",
        "coverage_95",
        "interval_width_90_mm",
        "nll",
    )


def accuracy_report(
    model: ErrorModel, X: np.ndarray, Y: np.ndarray, Y_uncalibrated: np.ndarray | None = None
) -> AccuracyReport:
    """Evaluate ``model`` on features ``X`` and labels ``Y`` (m, rad).

    ``Y_uncalibrated`` (default ``Y``) is the error without compensation, the baseline of
    ``improvement_pct = 100 (1 - mean_mm / uncalibrated_mean_mm)``.
    """
    Y = np.asarray(Y, dtype=float)
    Y0 = Y if Y_uncalibrated is None else np.asarray(Y_uncalibrated, dtype=float)
    ev = model.predict(X)
    res = Y - ev.mean
    pos = np.linalg.norm(res[:, :3], axis=1) * 1e3
    rot = np.linalg.norm(res[:, 3:], axis=1) * ARCMIN_PER_RAD
    base = float(np.linalg.norm(Y0[:, :3], axis=1).mean() * 1e3)
    coverage = {level: interval_coverage(ev, Y, level) for level in LEVELS}
    lo, hi = ev.interval(0.90)
    nll_mm = ev.nll(Y)[:, :3] + np.log(1e3)  # density per mm instead of per m
    return AccuracyReport.of(
        pos,
        rot,
        uncalibrated_mean_mm=base,
        improvement_pct=float(100.0 * (1.0 - pos.mean() / base)) if base > 0 else float("nan"),
        coverage_68=coverage[0.68],
        coverage_90=coverage[0.90],
        coverage_95=coverage[0.95],
        interval_width_90_mm=float((hi - lo)[:, :3].mean() * 1e3),
        nll=float(nll_mm.mean()),
    )


def interval_coverage(ev: Evidential, Y: np.ndarray, level: float) -> float:
    """The share of the position components of labels ``Y`` (m) inside the ``level`` intervals
    of prediction ``ev`` (NaN without points)."""
    lo, hi = ev.interval(level)
    inside = (Y[:, :3] >= lo[:, :3]) & (Y[:, :3] <= hi[:, :3])
    return float(inside.mean()) if inside.size else float("nan")


def past_envelope(
    model: ErrorModel,
    X: np.ndarray,
    margin_deg: float = MARGIN_DEG,
    margin_k: float = MARGIN_K,
) -> np.ndarray:
    """Per row of raw features ``X``: does a joint or a thermometer lie past what ``model`` was
    trained on (:mod:`learner.envelope`, what compensation marks ``envelope``)? All False
    without an envelope."""
    X = np.asarray(X, dtype=float)
    if model.envelope is None:
        return np.zeros(len(X), dtype=bool)
    temps = temperature_readings(model.spec, X)
    return outside(model.envelope, X[:, : model.spec.n_joints], temps, margin_deg, margin_k)


@dataclass(frozen=True)
class Trust:
    """Per row of ``X``, what compensation flags (:mod:`stream.compensation_guard`): the
    epistemic std of a position component over its limit (``epistemic``), a joint or a
    thermometer past the envelope (``envelope``), and the whole model when its day has not
    checked its intervals (``unverified``)."""

    over_epistemic_limit: np.ndarray
    past_envelope: np.ndarray
    unverified: bool

    @property
    def untrusted(self) -> np.ndarray:
        """Rows compensation would answer ``trusted: false`` (bool ``(N,)``)."""
        return self.over_epistemic_limit | self.past_envelope | self.unverified


def trust(model: ErrorModel, X: np.ndarray, epistemic_limit_mm: float) -> Trust:
    """What compensation would flag at raw features ``X`` with its ``epistemic_limit_mm`` (mm)."""
    epistemic_mm = np.sqrt(model.predict(X).epistemic()[:, :3]).max(axis=1) * 1e3
    return Trust(epistemic_mm > epistemic_limit_mm, past_envelope(model, X), bool(model.unverified))


def envelope_report(
    model: ErrorModel, X: np.ndarray, Y: np.ndarray, margin_deg: float = MARGIN_DEG
) -> dict:
    """How much of ``X, Y`` lies past the joint angles or temperatures ``model`` was trained on
    (a share, a count; how many by a joint, how many by a thermometer alone) and the accuracy
    of the rest (None when nothing is left)."""
    out = past_envelope(model, X, margin_deg)
    by_joint = past_envelope(model, X, margin_deg, margin_k=np.inf)
    inside = accuracy_report(model, X[~out], Y[~out]).to_dict() if (~out).any() else None
    return {
        "outside_share": float(out.mean()),
        "n_outside": int(out.sum()),
        "n_past_joints": int(by_joint.sum()),
        "n_past_temperatures_only": int((out & ~by_joint).sum()),
        "inside": inside,
    }
