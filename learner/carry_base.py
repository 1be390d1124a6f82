"""The base a carried day starts on: its frames from the day's first points and, where the line
says those points are a reference program spread over the workspace, its geometry as well.

A reference program (``robocal data reference-poses``) identifies the whole geometry, so the day's
own geometry is fitted under calibration's prior about the carried one, beside the frames: the arm
changes from day to day, not only its tracker. UR10, a tracker set up anew, after 100 reference
poses from the new series' first 1,000 training points: B→A 0.538 -> 0.440 mm, A→B 0.539 -> 0.448 mm
(BENCHMARKS.md, "A new set-up that starts with a reference program"). On a day's first points in
recorded order the same fit folds their region's error into the geometry (A→B 0.599 -> 0.644 mm): it
is a statement the line makes, never inferred, and it needs points that identify the geometry
(:data:`~learner.base.AUTO_MAX_CONDITION`).
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from kinematics.errors import IdentifiabilityError
from kinematics.model import RobotModel
from learner.base import AUTO_MAX_CONDITION, PhysicsBase, refit_base
from learner.carry import FramePriors, carried_frames
from learner.config import ContinualConfig
from learner.features import FeatureSpec


def carried_base(
    base: PhysicsBase,
    spec: FeatureSpec,
    X: np.ndarray,
    Y: np.ndarray,
    residual: np.ndarray,
    cfg: ContinualConfig,
) -> tuple[PhysicsBase, bool]:
    """``base`` for a new day from its first points ``X, Y`` (``residual``: what the network
    adds there): its frames (:func:`learner.carry.carried_frames`, whether they moved) and,
    with ``cfg.reference_program``, its geometry and effects fitted again on the points
    (:func:`learner.base.refit_base`) where they identify it, to the labels less the share of
    the network's residual the framed base leaves room for (:func:`residual_gain`); the note
    says which."""
    framed, moved = carried_frames(base, spec, X, Y, residual, FramePriors.of(cfg))
    if not cfg.reference_program:
        return framed, moved
    labels = np.asarray(Y, dtype=float) - residual_gain(framed, spec, X, Y, residual) * residual
    try:
        fitted = refit_base(framed, spec, X, labels, max_condition=AUTO_MAX_CONDITION)
    except IdentifiabilityError as exc:
        note = f"{framed.note}; reference program: geometry kept, {exc}"
        return replace(framed, note=note), moved
    note = (
        f"{framed.note}; reference program: geometry fitted again on its {len(X)} points, "
        f"condition number {fitted.condition:.3g}"
    )
    return replace(fitted, note=note, frame_sigma=None), moved


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
