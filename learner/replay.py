"""Replay strategies: which points of memory ∪ new batch train the model next.

The pool is always the current memory followed by the ``n_new`` new points. Max-error replay
(DESIGN.md) keeps the ``n_memory`` points the current model predicts worst; the others are the
comparison baselines of the reference experiment.

>>> import numpy as np
>>> MaxErrorReplay().select(np.array([0.1, 0.5, 0.2, 0.9]), 2, np.random.default_rng(0)).tolist()
[3, 1]
"""

from __future__ import annotations

import abc

import numpy as np

from kinematics.errors import ConfigError


class ReplayStrategy(abc.ABC):
    """Chooses the memory kept for the next training round."""

    name: str = ""

    @abc.abstractmethod
    def select(
        self,
        pool_errors: np.ndarray,
        n_memory: int,
        rng: np.random.Generator,
        *,
        n_new: int | None = None,
        n_seen: int = 0,
    ) -> np.ndarray:
        """Indices into the pool (memory first, then ``n_new`` new points) to keep.

        ``pool_errors`` are the prediction-error norms of the pool's points; ``n_seen`` counts
        the points seen before the new ones (reservoir sampling needs it).
        """


class MaxErrorReplay(ReplayStrategy):
    """Keep the ``n_memory`` points with the largest prediction error (ties: earlier first)."""

    name = "max_error"

    def select(self, pool_errors, n_memory, rng, *, n_new=None, n_seen=0):
        errors = np.asarray(pool_errors, dtype=float)
        return np.argsort(-errors, kind="stable")[:n_memory]


class ReservoirReplay(ReplayStrategy):
    """Reservoir sampling: every point seen so far is in memory with equal probability."""

    name = "reservoir"

    def select(self, pool_errors, n_memory, rng, *, n_new=None, n_seen=0):
        n_pool = len(pool_errors)
        n_new = n_pool if n_new is None else n_new
        keep = list(range(n_pool - n_new))
        for j in range(n_new):
            index = n_pool - n_new + j
            if len(keep) < n_memory:
                keep.append(index)
                continue
            slot = int(rng.integers(0, n_seen + j + 1))
            if slot < n_memory:
                keep[slot] = index
        return np.asarray(keep[:n_memory], dtype=int)


class NaiveReplay(ReplayStrategy):
    """Naive fine-tuning: train on the new batch only (no memory)."""

    name = "naive"

    def select(self, pool_errors, n_memory, rng, *, n_new=None, n_seen=0):
        n_pool = len(pool_errors)
        n_new = n_pool if n_new is None else n_new
        return np.arange(n_pool - n_new, n_pool)


class FullReplay(ReplayStrategy):
    """Full retraining: keep everything seen (memory grows without bound)."""

    name = "full"

    def select(self, pool_errors, n_memory, rng, *, n_new=None, n_seen=0):
        return np.arange(len(pool_errors))


REPLAY_STRATEGIES: dict[str, type[ReplayStrategy]] = {
    cls.name: cls for cls in (MaxErrorReplay, ReservoirReplay, NaiveReplay, FullReplay)
}


def replay_strategy(name: str) -> ReplayStrategy:
    """The strategy registered under ``name``."""
    if name not in REPLAY_STRATEGIES:
        raise ConfigError(
            f"replay strategy must be one of {tuple(REPLAY_STRATEGIES)}, got {name!r}"
        )
    return REPLAY_STRATEGIES[name]()
