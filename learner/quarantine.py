"""Quarantine of poisoned measurements: a point far outside the model's interval and its
neighbours' is not learned.

A bumped tracker or a swapped reflector moves the measured pose by tens of mm at once, far
more than a robot's own error changes from one point to the next; a genuine new effect (a
thermal drift, a region the model has not seen) moves the residuals of the new points alike,
or arrives where the model says it does not know. So a new point is quarantined when both

- its residual against the published model lies more than ``interval_threshold`` Student-t
  scales from the prediction in some component: far outside the model's predictive
  interval (where the model says it does not know, its interval is wide and the point
  passes), and
- its residual lies far from its neighbours' residuals: per component, the distance to their
  median in units of their MAD (normal-scaled), the Euclidean norm over components above
  ``threshold``. The neighbours are the latest ``history`` accepted points and the point's
  own batch, their residuals taken when each arrived.

Because the neighbours are accepted points, a burst does not become its own reference;
because their median follows what keeps arriving, a drift does. The neighbour scale is the
spread of the robot's own residuals in metres and radians, not the model's scale, which
widens and narrows with the adaptive interval. Before the first model there is no
prediction: each label is compared with the other labels in the same way against
``warmup_threshold``, which catches only gross outliers.

A shift that lasts ``release_after`` consecutive points is a change of the cell (a moved
tracker, a crash that bent a link), not a fault: the quarantine releases it, forgets the old
reference and follows.

>>> import numpy as np
>>> r = np.random.default_rng(0).normal(scale=1e-4, size=(40, 6))  # residuals, m and rad
>>> r[5, :3] += 0.02  # one point 20 mm off
>>> z = r / 1e-4  # standardized by the model's scale
>>> accepted, state = screen(r, z, QuarantineState.empty(), QuarantineConfig())
>>> np.flatnonzero(~accepted).tolist(), state.quarantined
([5], 1)
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from learner.config import QuarantineConfig
from learner.model import ErrorModel

#: Normal-consistency factor of the median absolute deviation.
MAD_TO_STD = 1.4826


@dataclass(frozen=True, kw_only=True)
class QuarantineState:
    """What the quarantine remembers: the residuals of the latest accepted points (``history``,
    (H, 6), m and rad), whether they are labels (before the first model) or model residuals,
    the current run of consecutive quarantined points and the cumulative counts."""

    history: np.ndarray
    labels: bool = True
    run: int = 0
    quarantined: int = 0
    released: int = 0

    @staticmethod
    def empty() -> QuarantineState:
        return QuarantineState(history=np.empty((0, 6)))

    def to_dict(self) -> dict:
        """Arrays and counters for a checkpoint (see :func:`state_from_dict`)."""
        return {
            "quarantine_history": self.history.copy(),
            "quarantine_meta": {
                "labels": self.labels,
                "run": self.run,
                "quarantined": self.quarantined,
                "released": self.released,
            },
        }


def state_from_dict(d: dict) -> QuarantineState:
    """Inverse of :meth:`QuarantineState.to_dict`; an empty state when the keys are absent
    (checkpoints written before the quarantine existed)."""
    if "quarantine_history" not in d:
        return QuarantineState.empty()
    meta = d.get("quarantine_meta", {})
    history = np.asarray(d["quarantine_history"], dtype=float).reshape(-1, 6)
    return QuarantineState(
        history=history,
        labels=bool(meta.get("labels", True)),
        run=int(meta.get("run", 0)),
        quarantined=int(meta.get("quarantined", 0)),
        released=int(meta.get("released", 0)),
    )


def robust_distance(r: np.ndarray, reference: np.ndarray) -> np.ndarray:
    """Per row of ``r`` (N, 6), the Euclidean norm over components of its distance to the
    median of ``reference`` (R, 6) in units of the reference's normal-scaled MAD."""
    center = np.median(reference, axis=0)
    spread = MAD_TO_STD * np.median(np.abs(reference - center), axis=0)
    return np.linalg.norm((r - center) / np.maximum(spread, 1e-12), axis=1)


def screen(
    r: np.ndarray, z: np.ndarray | None, state: QuarantineState, cfg: QuarantineConfig
) -> tuple[np.ndarray, QuarantineState]:
    """Which of the new points are accepted (bool per row), and the state after. ``r`` are
    their residuals (N, 6) in arrival order, ``z`` the same standardized by the model's
    predictive scale; ``z`` None means there is no model yet and ``r`` are the labels.
    Accepted points join the history (the newest ``cfg.history``); the history is forgotten
    when the kind of ``r`` changes (the first model) or a shift is released."""
    r = np.asarray(r, dtype=float)
    labels = z is None
    if not cfg.enabled or len(r) == 0:
        return np.ones(len(r), dtype=bool), state
    history = state.history if state.labels == labels else np.empty((0, 6))
    distance = robust_distance(r, np.concatenate([history, r]))
    if labels:
        far = distance > cfg.warmup_threshold
    else:
        far = (distance > cfg.threshold) & (np.abs(z).max(axis=1) > cfg.interval_threshold)
    accepted = ~far
    run, released = state.run, state.released
    for i in np.flatnonzero(far):
        run = run + 1 if i == 0 or far[i - 1] else 1
        if run >= cfg.release_after:  # a lasting shift: let it through from here on
            accepted[i:] = True
            history, run, released = np.empty((0, 6)), 0, released + 1
            break
    else:
        if not far[-1]:
            run = 0
    history = np.concatenate([history, r[accepted]])[-cfg.history :]
    quarantined = state.quarantined + int((~accepted).sum())
    new = replace(
        state, history=history, labels=labels, run=run, quarantined=quarantined, released=released
    )
    return accepted, new


def model_residuals(
    model: ErrorModel, X: np.ndarray, Y: np.ndarray
) -> tuple[np.ndarray, np.ndarray | None]:
    """What :func:`screen` compares: the residuals of ``Y`` against ``model`` and the same
    standardized by its predictive scale; the labels and None while the model is untrained."""
    Y = np.asarray(Y, dtype=float)
    if not model.is_fitted:
        return Y, None
    ev = model.predict(X)
    r = Y - ev.gamma
    return r, r / np.maximum(ev.scale(), 1e-15)


def holdout_mm(model: ErrorModel, X: np.ndarray, Y: np.ndarray) -> float:
    """Mean position error (mm) of ``model`` on held-out ``X, Y``; NaN without points."""
    if not len(X):
        return float("nan")
    return float(np.linalg.norm((model.predict(X).gamma - Y)[:, :3], axis=1).mean() * 1e3)


def withhold(before_mm: float, after_mm: float, n_holdout: int, cfg: QuarantineConfig) -> bool:
    """Whether the publish gate keeps the last model: its held-out error ``before_mm`` grew to
    ``after_mm`` by more than ``publish_tolerance`` on at least ``gate_min_points`` points."""
    if n_holdout < cfg.gate_min_points:
        return False
    return bool(after_mm > before_mm * (1.0 + cfg.publish_tolerance))
