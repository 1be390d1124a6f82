"""What a learner on a stream measures itself on: a held-out test set chosen by arrival, the
published model's error and uncertainty on it, and how old the replay memory's points are.

Every ``every``-th point to arrive (among those that passed the quarantine) is a test point,
never trained on; the set keeps the newest ``cap``. Memory age counts, per point in the replay
memory, how many batches ago it arrived.

>>> holdout_mask(8, 4, every=5).tolist()  # arrivals 8..11: the 10th (index 9) is held out
[False, True, False, False]
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from learner.model import ErrorModel


def holdout_mask(n_before: int, n: int, every: int) -> np.ndarray:
    """Which of ``n`` new points (after ``n_before`` arrivals) are test points: every
    ``every``-th by arrival."""
    k = n_before + np.arange(n)
    return (k % every) == every - 1


class HeldOut:
    """The newest ``cap`` held-out points: features ``x`` (N, F) raw SI, labels ``y`` (N, 6)."""

    def __init__(self, n_features: int, cap: int) -> None:
        self.x = np.empty((0, n_features))
        self.y = np.empty((0, 6))
        self.cap = cap

    def add(self, X: np.ndarray, Y: np.ndarray) -> None:
        """Append held-out points; the oldest beyond ``cap`` are dropped."""
        self.x = np.concatenate([self.x, X])[-self.cap :]
        self.y = np.concatenate([self.y, Y])[-self.cap :]

    def __len__(self) -> int:
        return len(self.y)


@dataclass(frozen=True, kw_only=True)
class HeldOutMetrics:
    """The published model on the test set: position error mean and max, mean aleatoric and
    epistemic std of the position components and the 90th percentile of the latter (mm)."""

    mean_mm: float = float("nan")
    max_mm: float = float("nan")
    aleatoric_mm: float = float("nan")
    epistemic_mm: float = float("nan")
    epistemic_p90_mm: float = float("nan")


def heldout_metrics(model: ErrorModel, X: np.ndarray, Y: np.ndarray) -> HeldOutMetrics:
    """:class:`HeldOutMetrics` of ``model`` on ``X, Y`` (all NaN without points)."""
    if not len(Y):
        return HeldOutMetrics()
    ev = model.predict(X)
    err = np.linalg.norm(ev.mean[:, :3] - Y[:, :3], axis=1) * 1e3
    epi = np.sqrt(ev.epistemic()[:, :3]).mean(axis=1) * 1e3
    return HeldOutMetrics(
        mean_mm=float(err.mean()),
        max_mm=float(err.max()),
        aleatoric_mm=float(np.sqrt(ev.aleatoric()[:, :3]).mean() * 1e3),
        epistemic_mm=float(epi.mean()),
        epistemic_p90_mm=float(np.percentile(epi, 90)),
    )


class MemoryAge:
    """The batch each trained-on point arrived in, keyed by its feature row, so the replay
    memory's composition by age can be reported."""

    def __init__(self) -> None:
        self.seq: dict[bytes, int] = {}

    def record(self, X: np.ndarray, seq: int) -> None:
        """Points of batch ``seq`` handed to training."""
        for row in X:
            self.seq[row.tobytes()] = seq

    def keep(self, memory_x: np.ndarray) -> None:
        """Forget the points no longer in the memory."""
        in_memory = {r.tobytes() for r in memory_x}
        self.seq = {k: v for k, v in self.seq.items() if k in in_memory}

    def histogram(self, memory_x: np.ndarray, last_seq: int) -> tuple[int, ...]:
        """Memory points per age in batches (index 0: the latest batch ``last_seq``)."""
        ages = [last_seq - self.seq.get(r.tobytes(), last_seq) for r in memory_x]
        if not ages:
            return ()
        return tuple(int(c) for c in np.bincount(np.asarray(ages, dtype=int), minlength=1))

    def arrays(self) -> tuple[np.ndarray, np.ndarray]:
        """Rows (N, F) and their batch numbers (N,), for a checkpoint."""
        ages = np.array(list(self.seq.values()), dtype=np.int64)
        rows = np.array([np.frombuffer(k, dtype=float) for k in self.seq]).reshape(len(ages), -1)
        return rows, ages

    @staticmethod
    def from_arrays(rows: np.ndarray, ages: np.ndarray) -> MemoryAge:
        """Inverse of :meth:`arrays`."""
        age = MemoryAge()
        age.seq = {
            np.ascontiguousarray(r).tobytes(): int(a) for r, a in zip(rows, ages, strict=True)
        }
        return age
