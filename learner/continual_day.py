"""A carried day in the continual learner: started from its first points, its frames followed
as its points come, the models moved onto a new base with the memory's labels.

These work on a :class:`~learner.continual.ContinualLearner`'s memory, held-out set and models
(typed ``Any``, as in :mod:`learner.continual_state`: importing the class would be a cycle).
The learner's ``carry`` and ``rebase`` call them, and each of its updates calls :func:`follow`.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from kinematics.model import RobotModel
from kinematics.outliers import without_gross_rows
from learner.base import PhysicsBase
from learner.carry import MIN_DAY_POINTS, CarriedDay, position_factor, scale_needed, unverified
from learner.carry_base import DayPoints, carried_base, checking_labels, day_frames
from learner.continual_records import checked_batch


def carry(learner: Any, X: np.ndarray, Y: np.ndarray) -> float:
    """Start a new day or cell from its first points ``X, Y``: re-identify the base's frames
    (:func:`learner.carry_base.carried_base`), empty the held-out set (another day's) and fit
    the carried network's gain on these points (:meth:`ErrorModel.weigh_residual`); returns it.
    Gain and scale are re-fitted on the day's held-out points once :data:`MIN_DAY_POINTS`
    are there (its mark kept until they are spread: :func:`~learner.carry.hold_day`). Until
    then the scale is the model's times its ``drift_scale`` (not again on a young day), or,
    where the frames moved or these points need a far wider one, no narrower than they show
    (:func:`~learner.carry_base.checking_labels`) and ``unverified``
    (:func:`~learner.carry.unverified`); a reference program that fitted the geometry checks
    them itself: no narrower than its folds need, times the drift. Its points refit frames
    (gross outliers left out: one 1 m off had moved a freely fitted day's base 33 mm)."""
    X, Y = without_gross_rows(*checked_batch(X, Y, learner.model.spec.n_features))
    needed, miss = scale_needed(learner.model, X, Y)
    young = learner.day_scale is not None and len(learner._cal_x) < MIN_DAY_POINTS
    drift = np.ones_like(learner.model.drift_scale) if young else learner.model.drift_scale
    points = DayPoints(learner.model.spec, X, Y, learner.model.residual(X))
    old, start = learner.base, carried_base(learner.base, points, learner.cfg)
    source = start.base if learner.cfg.reference_program else old  # the day's refits' centre
    learner.day = CarriedDay.start(source, len(X), X.shape[1], learner.n_seen, start.aside)
    rebase(learner, start.base)
    learner._cal_x, learner._cal_y = learner._cal_x[:0], learner._cal_y[:0]
    learner.trained.residual_gain = learner.model.weigh_residual(X, Y)
    scale = learner.model.interval_scale * drift  # a later day, as its own last hours showed
    mark = unverified(start.moved, miss / position_factor(drift), len(X))
    labels = checking_labels(start, old, points, learner.cfg)
    if labels is not None:
        needed = learner.model.calibrate(X, labels)
    if start.refitted:  # minutes of poses: they widen the scale, never narrow it
        scale, mark = np.maximum(scale, needed * drift), ""
    elif mark:
        scale = np.maximum(scale, needed)
    learner.model.interval_scale, learner.model.unverified = scale, mark
    learner.day_scale = scale / np.exp(learner.aci_log_scale)
    return learner.trained.residual_gain


def rebase(learner: Any, base: PhysicsBase, keep: np.ndarray | None = None) -> None:
    """Put both models on a new physics base (e.g. frames re-identified on a new day); the
    memory's labels move with it so that each point keeps its residual. With ``keep`` (a
    carried day's frames fitted again) the memory points it marks and the held-out set,
    all measured in the day's frames, keep their labels."""
    nominal = RobotModel(learner.model.spec.description)

    def shift(x: np.ndarray) -> np.ndarray:
        return base.error(learner.model.spec, x, nominal) - learner.trained.base_error(x)

    if keep is None:
        learner._cal_y += shift(learner._cal_x)
        keep = np.zeros(len(learner._mem_x), dtype=bool)
    learner._mem_y += np.where(keep[:, None], 0.0, shift(learner._mem_x))
    for model in (learner.model, learner.trained):
        model.base = base


def follow(learner: Any, X: np.ndarray, Y: np.ndarray) -> None:
    """Add a carried day's trained points; when they have doubled, fit its frames again on
    all of them from the frames it was carried from, and weigh what a reference program
    set aside on its held-out points (:func:`~learner.carry_base.day_frames`)."""
    if learner.day is None:
        return
    limit = learner.cfg.day_frame_points
    day = learner.day = learner.day.add(X, Y, limit)
    if not day.due(limit):
        return
    spec, residual = learner.model.spec, learner.model.residual
    trained = DayPoints(spec, day.x, day.y, residual(day.x))
    held = DayPoints(spec, learner._cal_x, learner._cal_y, residual(learner._cal_x))
    base, learner.day = day_frames(day, learner.base, trained, held, learner.cfg)
    rebase(learner, base, keep=day.holds(learner._mem_x))
