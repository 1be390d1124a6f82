"""A continual learner's network trained afresh on its memory as the stream grows.

Warm-started fine-tuning fits the memory but stops generalising: a network that learned
batch after batch ends far from one trained once on the same points (Ash & Adams 2020, "On
warm-starting neural network training"). On UR10 Series B streamed in recorded order the
published model ended at 0.321 mm where a network trained afresh on its final memory, the
same base and held-out set, reached 0.186 mm (batch: 0.176 mm). With
``ContinualConfig.refresh_growth`` (0, off, by default) each time the points given grow by
that factor a fresh network (new weights from the model's seed, trained as batch training
trains, early stopping on the held-out set) is trained on the memory, and the learner keeps
it where it predicts the held-out points better than the model it publishes. At 2: B in
recorded order 0.289 -> 0.191 mm (three seeds), four random arms 0.0870 -> 0.0844 mm; but
where the memory drops points the warm network still knows, the updates after a refresh end
worse: UR10 A 0.115 -> 0.120 mm (memory 4,000 of 10,720 points), the simulated paper
campaign at N_m 2,000 0.0244 -> 0.0255 mm (seeds 0-8; on seed 0 the fresh networks from the
second on were better on the held-out points at p < 0.003): BENCHMARKS.md, "A fresh
network on every stream, measured again". On a carried day ``day_refresh_growth`` (2, on)
counts the day's own points and the day's held-out points decide: UR10 A's model carried
through Series B 0.362 -> 0.281 mm ("A fresh network on a carried day"). The schedule is
geometric, so the fits cost a constant multiple of the last one.

>>> [n for n in range(50, 1000, 50) if grew(n, n + 50, 50, 2.0)]
[50, 150, 350, 750]
"""

from __future__ import annotations

import math

import numpy as np

from learner.carry import MIN_DAY_POINTS
from learner.config import ContinualConfig
from learner.model import MIN_CALIBRATION, ErrorModel
from learner.training import Trainer


def grew(before: int, after: int, init: int, factor: float) -> bool:
    """Whether the points given passed ``init`` times a power of ``factor`` (``before`` ->
    ``after``); never for a ``factor`` of 0."""
    if factor == 0 or after < init:
        return False

    def level(n: int) -> int:
        return -1 if n < init else math.floor(math.log(n / init) / math.log(factor) + 1e-9)

    return level(after) > level(before)


def refresh_due(
    cfg: ContinualConfig, day_start: int | None, before: int, after: int, n_held_out: int
) -> bool:
    """Whether a learner given ``before`` -> ``after`` points, ``n_held_out`` held out, trains a
    fresh network now: as they grow by ``refresh_growth``, or on a day carried after
    ``day_start`` points as the day's own grow by ``day_refresh_growth``, once
    :data:`~learner.carry.MIN_DAY_POINTS` of them are held out (fewer cannot tell the day)."""
    if day_start is None:
        due = grew(before, after, cfg.init, cfg.refresh_growth)
        return due and n_held_out >= MIN_CALIBRATION
    due = grew(before - day_start, after - day_start, cfg.init, cfg.day_refresh_growth)
    return due and n_held_out >= MIN_DAY_POINTS


def fresh_fit(
    model: ErrorModel,
    X: np.ndarray,
    Y: np.ndarray,
    X_val: np.ndarray,
    Y_val: np.ndarray,
    trainer: Trainer | None = None,
) -> ErrorModel:
    """A fresh network of ``model``'s kind (:meth:`ErrorModel.clone`: its base, configs and
    seed) trained on ``X, Y`` as batch training trains (its rate, schedule, epochs, early
    stopping), validated and calibrated on ``X_val, Y_val``; it keeps ``model``'s envelope
    (every joint angle and temperature the learner trained on, not only the memory's) and
    drift scale."""
    fresh = model.clone()
    fresh.envelope, fresh.drift_scale = model.envelope, model.drift_scale.copy()
    fresh.fit(X, Y, X_val, Y_val, val_fraction=0.0, trainer=trainer)
    return fresh
