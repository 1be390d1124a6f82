"""What a continual learner reports: the metrics of each update and its replay memory."""

from __future__ import annotations

from dataclasses import asdict, dataclass

import numpy as np


@dataclass(frozen=True, kw_only=True)
class UpdateMetrics:
    """What one update did. Errors are position-error norms in mm: ``batch_*`` of the new
    points before training (prequential), ``train_*`` of the memory after training,
    ``holdout_mm`` the published model's median on the held-out set (NaN without one).
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

    def to_dict(self) -> dict:
        return asdict(self)


@dataclass(frozen=True)
class Memory:
    """The replay memory: features ``x`` (M, F) raw SI and labels ``y`` (M, 6)."""

    x: np.ndarray
    y: np.ndarray

    def __len__(self) -> int:
        return int(self.x.shape[0])
