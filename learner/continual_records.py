"""What a continual learner takes and reports: a checked batch, the metrics of each update
and its replay memory."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import asdict, dataclass
from typing import TYPE_CHECKING

import numpy as np

from kinematics.errors import DatasetError
from learner.training import TrainReport

if TYPE_CHECKING:
    from learner.model import ErrorModel


@dataclass(frozen=True, kw_only=True)
class UpdateMetrics:
    """What one update did. Errors are position-error norms in mm: ``batch_*`` of the new
    points before training (prequential), ``train_*`` of the memory after training,
    ``holdout_mm`` the published model's median on the held-out set (NaN without one).
    ``batch_coverage_90`` is the share of the new points' position components inside the 90 %
    intervals the published model gave them before it learned them: what a line that asked it
    then got (NaN while there is no model).
    ``quarantined`` counts this step's points kept out; ``withheld`` says the gate kept the
    last published model."""

    version: int
    n_seen: int
    n_new: int
    memory_size: int
    new_in_memory: int
    epochs: int
    train_time_s: float
    batch_mean_mm: float
    batch_max_mm: float
    train_mean_mm: float
    skipped_steps: int
    quarantined: int = 0
    withheld: bool = False
    holdout_mm: float = float("nan")
    batch_coverage_90: float = float("nan")

    def to_dict(self) -> dict:
        return asdict(self)

    @classmethod
    def of(
        cls,
        version: int,
        n_seen: int,
        n_new: int,
        memory_size: int,
        new_in_memory: int,
        report: TrainReport | None,
        train_time_s: float,
        batch_err: np.ndarray | None,
        train_mean_mm: float,
    ) -> UpdateMetrics:
        """A step's metrics from its counts, training report (None: it trained nothing), the
        new points' position errors before it (m; None: none) and the memory's error after."""
        batch_err = np.full(1, np.nan) if batch_err is None else batch_err
        return cls(
            version=version,
            n_seen=n_seen,
            n_new=n_new,
            memory_size=memory_size,
            new_in_memory=new_in_memory,
            epochs=0 if report is None else report.epochs,
            train_time_s=train_time_s,
            batch_mean_mm=float(batch_err.mean() * 1e3),
            batch_max_mm=float(batch_err.max() * 1e3),
            train_mean_mm=train_mean_mm,
            skipped_steps=0 if report is None else report.skipped_steps,
        )


def prequential(updates: Sequence[UpdateMetrics]) -> dict:
    """A stream's own check of its answers: each update's new points scored before it learned
    them, pooled over ``updates`` by the points each learned (updates that scored none left
    out): mean position error (mm), 90 % coverage, and how many points that is. With
    ``--test-fraction 0`` there is no test set, and this is the honest figure a day can give.

    >>> from dataclasses import replace
    >>> a = UpdateMetrics.of(2, 200, 90, 90, 90, None, 0.1, np.full(90, 1e-3), 0.5)
    >>> b = UpdateMetrics.of(3, 300, 30, 120, 30, None, 0.1, np.full(30, 3e-3), 0.5)
    >>> p = prequential([replace(a, batch_coverage_90=1.0), replace(b, batch_coverage_90=0.6)])
    >>> p["n_points"], round(p["mean_mm"], 3), round(p["coverage_90"], 3)
    (120, 1.5, 0.9)
    """
    scored = [m for m in updates if m.n_new and np.isfinite(m.batch_coverage_90)]
    n = np.array([m.n_new for m in scored], dtype=float)
    if not n.sum():
        return {"n_points": 0, "mean_mm": float("nan"), "coverage_90": float("nan")}
    return {
        "n_points": int(n.sum()),
        "mean_mm": float(np.average([m.batch_mean_mm for m in scored], weights=n)),
        "coverage_90": float(np.average([m.batch_coverage_90 for m in scored], weights=n)),
    }


def memory_mm(model: ErrorModel, X: np.ndarray, Y: np.ndarray) -> float:
    """Mean position error (mm) of ``model`` on its memory ``X, Y``: NaN before either."""
    if not (model.is_fitted and len(X)):
        return float("nan")
    return float(np.linalg.norm((model.predict(X).gamma - Y)[:, :3], axis=1).mean() * 1e3)


@dataclass(frozen=True)
class Memory:
    """The replay memory: features ``x`` (M, F) raw SI and labels ``y`` (M, 6)."""

    x: np.ndarray
    y: np.ndarray

    def __len__(self) -> int:
        return int(self.x.shape[0])


def checked_batch(X: np.ndarray, Y: np.ndarray, n_features: int) -> tuple[np.ndarray, np.ndarray]:
    """A batch's features ``(N, n_features)`` and labels ``(N, 6)`` as float arrays, or a
    DatasetError naming what is wrong with them."""
    X = np.asarray(X, dtype=float)
    Y = np.asarray(Y, dtype=float)
    if X.ndim != 2 or X.shape[1] != n_features:
        raise DatasetError(f"batch features must have shape (N, {n_features}), got {X.shape}")
    if Y.shape != (X.shape[0], 6):
        raise DatasetError(f"batch labels must have shape ({X.shape[0]}, 6), got {Y.shape}")
    if not (np.all(np.isfinite(X)) and np.all(np.isfinite(Y))):
        raise DatasetError("batch contains non-finite features or labels")
    return X, Y
