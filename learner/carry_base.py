"""The base a carried day starts on: its frames from the day's first points and, where the line
says those points are a reference program spread over the workspace, its geometry as well.

A reference program (``robocal data reference-poses``) identifies the whole geometry, so the day's
own geometry is fitted under calibration's prior about the carried one, beside the frames: the arm
changes from day to day, not only its tracker. UR10, a tracker set up anew, after 100 reference
poses from the new series' first 1,000 training points: B→A 0.538 -> 0.440 mm, A→B 0.539 -> 0.448 mm
(BENCHMARKS.md, "A new set-up that starts with a reference program"). On a day's first points in
recorded order the same fit folds their region's error into the geometry (A→B 0.599 -> 0.644 mm): it
is a statement the line makes, never inferred, and it needs points that identify the geometry
(:data:`~learner.base.AUTO_MAX_CONDITION`). Spread over the workspace, the program also checks
the day's intervals: each pose as the base fitted without its fold misses it
(:func:`checking_labels`).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, replace

import numpy as np

from kinematics.errors import IdentifiabilityError
from kinematics.model import RobotModel
from learner.base import AUTO_MAX_CONDITION, PhysicsBase, refit_base
from learner.carry import FramePriors, carried_frames, reidentify_frames
from learner.config import ContinualConfig
from learner.features import FeatureSpec


@dataclass(frozen=True)
class DayBase:
    """The base a carried day starts on (:func:`carried_base`): whether its frames ``moved``,
    and whether a reference program fitted its geometry again (``refitted``)."""

    base: PhysicsBase
    moved: bool
    refitted: bool = False


def carried_base(
    base: PhysicsBase,
    spec: FeatureSpec,
    X: np.ndarray,
    Y: np.ndarray,
    residual: np.ndarray,
    cfg: ContinualConfig,
) -> DayBase:
    """``base`` for a new day from its first points ``X, Y`` (``residual``: what the network
    adds there): its frames (:func:`learner.carry.carried_frames`, whether they moved) and,
    with ``cfg.reference_program``, its geometry and effects fitted again on the points
    (:func:`learner.base.refit_base`) where they identify it, to the labels less the share of
    the network's residual the framed base leaves room for (:func:`residual_gain`); the note
    says which."""
    framed, moved = carried_frames(base, spec, X, Y, residual, FramePriors.of(cfg))
    if not cfg.reference_program:
        return DayBase(framed, moved)
    labels = np.asarray(Y, dtype=float) - residual_gain(framed, spec, X, Y, residual) * residual
    try:
        fitted = refit_base(framed, spec, X, labels, max_condition=AUTO_MAX_CONDITION)
    except IdentifiabilityError as exc:
        note = f"{framed.note}; reference program: geometry kept, {exc}"
        return DayBase(replace(framed, note=note), moved)
    note = (
        f"{framed.note}; reference program: geometry fitted again on its {len(X)} points, "
        f"condition number {fitted.condition:.3g}"
    )
    return DayBase(replace(fitted, note=note, frame_sigma=None), moved, refitted=True)


def checking_labels(
    start: DayBase,
    base: PhysicsBase,
    spec: FeatureSpec,
    X: np.ndarray,
    Y: np.ndarray,
    residual: np.ndarray,
    cfg: ContinualConfig,
) -> np.ndarray | None:
    """The labels on which a day carried from ``base`` to ``start`` checks its intervals, each
    of its first points ``X, Y`` as the same fit without its fold leaves it
    (:func:`held_out_labels`): a reference program's whole
    :func:`carried_base` where it fitted the geometry (spread over the workspace, its folds
    check the intervals everywhere), else a move's frames; None where the frames held."""
    if start.refitted:

        def fit_on(rows: np.ndarray) -> PhysicsBase:
            return carried_base(base, spec, X[rows], Y[rows], residual[rows], cfg).base

    elif start.moved:
        priors = FramePriors.of(cfg)

        def fit_on(rows: np.ndarray) -> PhysicsBase:
            return reidentify_frames(
                base,
                spec,
                X[rows],
                Y[rows],
                residual=residual[rows],
                prior_m=priors.moved_m,
                tracker_free=priors.tracker_free,
            )

    else:
        return None
    return held_out_labels(start.base, spec, X, Y, fit_on)


def held_out_labels(
    fitted: PhysicsBase,
    spec: FeatureSpec,
    X: np.ndarray,
    Y: np.ndarray,
    fit_on: Callable[[np.ndarray], PhysicsBase],
    folds: int = 5,
) -> np.ndarray:
    """``Y`` moved so that ``fitted`` (a base fitted on all of ``X, Y``) leaves at each point
    what ``fit_on(rows)``, the same fit on the other folds' rows, leaves: calibrating
    intervals on them measures how far the fit misses points it was not fitted to, not how
    well it fits its own (on 10 points the second is far smaller). Fewer than 2 points: ``Y``
    as it is."""
    out = np.array(Y, dtype=float)
    if len(X) < 2:
        return out
    nominal = RobotModel(spec.description)
    out += fitted.error(spec, X, nominal)
    for fold in np.array_split(np.arange(len(X)), min(folds, len(X))):
        without = fit_on(np.setdiff1d(np.arange(len(X)), fold))
        out[fold] -= without.error(spec, X[fold], nominal)
    return out


def residual_gain(
    base: PhysicsBase, spec: FeatureSpec, X: np.ndarray, Y: np.ndarray, residual: np.ndarray
) -> float:
    """The share in [0, 1] of the carried network's ``residual`` (N, 6) that explains what
    ``base`` leaves of the positions in ``Y`` (least squares, m): what
    :meth:`~learner.model.ErrorModel.weigh_residual` fits once the model stands on ``base``,
    needed here before it does, since the network learned its residual on another day."""
    left = (
        np.asarray(Y, dtype=float)[:, :3] - base.error(spec, X, RobotModel(spec.description))[:, :3]
    )
    power = float(np.sum(residual[:, :3] ** 2))
    gain = float(np.sum(residual[:, :3] * left)) / power if power > 0 else 1.0
    return float(np.clip(gain, 0.0, 1.0))
