"""Quarantine of poisoned measurements: a point far outside the model's interval and its
neighbours' is not learned.

A bumped tracker or a swapped reflector moves the measured pose by tens of mm at once, more
than the robot's own error varies and far more than that error changes from one point to the
next; a genuine new effect (a thermal drift, a region the model has not seen) moves the
residuals of the new points alike, stays within what the robot's error does, or arrives where
the model says it does not know. So a new point is quarantined when all of

- its residual against the published model lies more than ``interval_threshold`` Student-t
  scales from the prediction in some component: far outside the model's predictive
  interval (where the model says it does not know, its interval is wide and the point
  passes);
- its residual lies far from its neighbours' residuals: per component, the distance to their
  median in units of their MAD (normal-scaled), the Euclidean norm over components above
  ``threshold``. The neighbours are the latest ``history`` accepted points and the point's
  own batch, their residuals taken when each arrived;
- its label (the measured pose error against the nominal model) lies more than
  ``label_threshold`` such units from its neighbours' labels: a measurement the robot's own
  error does not explain. A model that extrapolates badly in a new region produces large
  residuals on points whose labels are ordinary; those pass.

Because the neighbours are accepted points, a burst does not become its own reference;
because their median follows what keeps arriving, a drift does. The neighbour scales are the
spread of the robot's own residuals and errors in metres and radians, not the model's scale,
which widens and narrows with the adaptive interval. Before the first model there is no
prediction: the label alone is judged, against ``warmup_threshold``, which catches only gross
outliers.

A shift that lasts ``release_after`` consecutive points is a change of the cell (a moved
tracker, a crash that bent a link), not a fault: the quarantine releases it, forgets the old
neighbours and follows.

>>> import numpy as np
>>> rng = np.random.default_rng(0)
>>> y = rng.normal(scale=1e-3, size=(40, 6))  # labels: the robot's error, m and rad
>>> r = rng.normal(scale=1e-4, size=(40, 6))  # residuals against the model
>>> y[5, :3] += 0.02; r[5, :3] += 0.02  # one point 20 mm off
>>> accepted, state = screen(y, r, r / 1e-4, QuarantineState.empty(), QuarantineConfig())
>>> np.flatnonzero(~accepted).tolist(), state.quarantined
([5], 1)
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from kinematics.outliers import robust_distance
from learner.config import QuarantineConfig
from learner.model import ErrorModel


@dataclass(frozen=True, kw_only=True)
class QuarantineState:
    """What the quarantine remembers of the latest accepted points: their ``labels`` and
    ``residuals`` ((H, 6), m and rad; residuals only from the first model on), the current run
    of consecutive quarantined points and the cumulative counts."""

    labels: np.ndarray
    residuals: np.ndarray
    run: int = 0
    quarantined: int = 0
    released: int = 0

    @staticmethod
    def empty() -> QuarantineState:
        return QuarantineState(labels=np.empty((0, 6)), residuals=np.empty((0, 6)))

    def to_dict(self) -> dict:
        """Arrays and counters for a checkpoint (see :func:`state_from_dict`)."""
        return {
            "quarantine_labels": self.labels.copy(),
            "quarantine_residuals": self.residuals.copy(),
            "quarantine_meta": {
                "run": self.run,
                "quarantined": self.quarantined,
                "released": self.released,
            },
        }


def state_from_dict(d: dict) -> QuarantineState:
    """Inverse of :meth:`QuarantineState.to_dict`; an empty state when the keys are absent
    (checkpoints written before the quarantine existed)."""
    if "quarantine_labels" not in d:
        return QuarantineState.empty()
    meta = d.get("quarantine_meta", {})
    return QuarantineState(
        labels=np.asarray(d["quarantine_labels"], dtype=float).reshape(-1, 6),
        residuals=np.asarray(d["quarantine_residuals"], dtype=float).reshape(-1, 6),
        run=int(meta.get("run", 0)),
        quarantined=int(meta.get("quarantined", 0)),
        released=int(meta.get("released", 0)),
    )


def screen(
    y: np.ndarray,
    r: np.ndarray | None,
    z: np.ndarray | None,
    state: QuarantineState,
    cfg: QuarantineConfig,
) -> tuple[np.ndarray, QuarantineState]:
    """Which of the new points are accepted (bool per row), and the state after. ``y`` are
    their labels (N, 6) in arrival order, ``r`` their residuals against the published model
    and ``z`` the same standardized by its predictive scale; both None before the first model.
    Accepted points join the neighbours (the newest ``cfg.history``); a released shift
    forgets them."""
    y = np.asarray(y, dtype=float)
    if not cfg.enabled or len(y) == 0:
        return np.ones(len(y), dtype=bool), state
    labels, residuals = state.labels, state.residuals
    label_far = robust_distance(y, np.concatenate([labels, y]))
    if r is None or z is None:
        far = label_far > cfg.warmup_threshold
    else:
        far = (label_far > cfg.label_threshold) & (np.abs(z).max(axis=1) > cfg.interval_threshold)
        far[far] = robust_distance(r, np.concatenate([residuals, r]))[far] > cfg.threshold
    accepted = ~far
    run, released = state.run, state.released
    for i in np.flatnonzero(far):
        run = run + 1 if i == 0 or far[i - 1] else 1
        if run >= cfg.release_after:  # a lasting shift: let it through from here on
            accepted[i:] = True
            labels, residuals = np.empty((0, 6)), np.empty((0, 6))
            run, released = 0, released + 1
            break
    else:
        if not far[-1]:
            run = 0
    labels = np.concatenate([labels, y[accepted]])[-cfg.history :]
    if r is not None:
        residuals = np.concatenate([residuals, r[accepted]])[-cfg.history :]
    return accepted, QuarantineState(
        labels=labels,
        residuals=residuals,
        run=run,
        quarantined=state.quarantined + int((~accepted).sum()),
        released=released,
    )


def model_residuals(
    model: ErrorModel, X: np.ndarray, Y: np.ndarray
) -> tuple[np.ndarray | None, np.ndarray | None]:
    """The residuals of ``Y`` against ``model`` and the same standardized by its predictive
    scale, as :func:`screen` takes them; (None, None) while the model is untrained."""
    if not model.is_fitted:
        return None, None
    ev = model.predict(X)
    r = np.asarray(Y, dtype=float) - ev.gamma
    return r, r / np.maximum(ev.scale(), 1e-15)


def holdout_mm(model: ErrorModel, X: np.ndarray, Y: np.ndarray) -> float:
    """Median position error (mm) of ``model`` on held-out ``X, Y``; NaN without points. The
    median, not the mean: a few poisoned points that reached the held-out set (quarantine off,
    or missed) would dominate a mean and let the poisoned model pass as an improvement (a
    20-50 mm burst, gate on the mean: 0 updates withheld; BENCHMARKS.md)."""
    if not len(X):
        return float("nan")
    return float(np.median(np.linalg.norm((model.predict(X).gamma - Y)[:, :3], axis=1)) * 1e3)


def withhold(before_mm: float, after_mm: float, n_holdout: int, cfg: QuarantineConfig) -> bool:
    """Whether the publish gate keeps the last model: its held-out error ``before_mm`` grew
    to ``after_mm`` by more than ``publish_tolerance`` on at least ``gate_min_points`` points."""
    if n_holdout < cfg.gate_min_points:
        return False
    return bool(after_mm > before_mm * (1.0 + cfg.publish_tolerance))
