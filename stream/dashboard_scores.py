"""What the dashboard draws of each new point (pure numpy): errors, their bands, coverage.

A point is scored by the model the dashboard holds when the point arrives: the model that
lags the stream (it has not trained on the point yet), so its error is prequential, larger
than the held-out test error of the newest model. Position errors are norms (mm) of the
3-vector; their bands are quantiles of that norm under the model's Student-t predictive
(interval) or under the Normal of its mean alone (epistemic), from seeded draws.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from learner.evidential import Evidential

LEVEL = 0.9
N_DRAWS = 400


def norm_band(
    center: np.ndarray,
    scale: np.ndarray,
    df: np.ndarray | None,
    level: float,
    rng: np.random.Generator,
    n_draws: int = N_DRAWS,
) -> np.ndarray:
    """Central ``level`` band ``(N, 2)`` of ``|center + scale * T|`` per row, ``T`` Student-t
    with ``df`` degrees of freedom per component (Normal when ``df`` is None); same units."""
    n, k = center.shape
    if df is None:
        draws = rng.standard_normal((n, n_draws, k))
    else:
        draws = rng.standard_t(np.broadcast_to(df[:, None, :], (n, n_draws, k)))
    norms = np.linalg.norm(center[:, None, :] + scale[:, None, :] * draws, axis=2)
    lo, hi = np.quantile(norms, [(1.0 - level) / 2.0, (1.0 + level) / 2.0], axis=1)
    return np.column_stack([lo, hi])


@dataclass(frozen=True, kw_only=True)
class PointScores:
    """Per-point position errors (mm): measured, predicted by the lagging model with its
    bands, what is left after the prediction with its bands, and which measured components
    (x, y, z) fell inside the model's ``level`` interval."""

    measured_mm: np.ndarray
    predicted_mm: np.ndarray | None = None
    predicted_band_mm: np.ndarray | None = None
    predicted_epistemic_mm: np.ndarray | None = None
    left_mm: np.ndarray
    left_band_mm: np.ndarray | None = None
    left_epistemic_mm: np.ndarray | None = None
    inside: np.ndarray | None = None


def score_points(
    errors_m: np.ndarray, prediction: Evidential | None, seed: int = 0, level: float = LEVEL
) -> PointScores:
    """Scores of measured pose errors ``(N, 6)`` (m, rad) against a prediction of them (None
    before the first model: then what is left is the whole measured error)."""
    e = np.asarray(errors_m, dtype=float)[:, :3]
    measured = np.linalg.norm(e, axis=1) * 1e3
    if prediction is None:
        return PointScores(measured_mm=measured, left_mm=measured)
    rng = np.random.default_rng(seed)
    mean = prediction.mean[:, :3]
    scale, df = prediction.scale()[:, :3], 2.0 * prediction.alpha[:, :3]
    epi = np.sqrt(prediction.epistemic()[:, :3])
    lo, hi = prediction.interval(level)
    zero = np.zeros_like(mean)
    return PointScores(
        measured_mm=measured,
        predicted_mm=np.linalg.norm(mean, axis=1) * 1e3,
        predicted_band_mm=norm_band(mean, scale, df, level, rng) * 1e3,
        predicted_epistemic_mm=norm_band(mean, epi, None, level, rng) * 1e3,
        left_mm=np.linalg.norm(e - mean, axis=1) * 1e3,
        left_band_mm=norm_band(zero, scale, df, level, rng) * 1e3,
        left_epistemic_mm=norm_band(zero, epi, None, level, rng) * 1e3,
        inside=(e >= lo[:, :3]) & (e <= hi[:, :3]),
    )


def rolling_coverage(history: np.ndarray, inside: np.ndarray, window: int) -> np.ndarray:
    """Fraction of components inside their interval over the last ``window`` points, at each
    new point; ``history`` holds the earlier points' per-point fractions (most recent last)."""
    frac = np.concatenate([history, inside.mean(axis=1)])
    csum = np.concatenate([[0.0], np.cumsum(frac)])
    end = np.arange(len(history) + 1, len(frac) + 1)
    start = np.maximum(end - window, 0)
    return (csum[end] - csum[start]) / (end - start)


def error_colors(error_mm: np.ndarray, scale_mm: float) -> np.ndarray:
    """RGB colours from green (0) through yellow to red (``>= scale_mm``)."""
    s = np.clip(np.asarray(error_mm, dtype=float) / max(scale_mm, 1e-9), 0.0, 1.0)
    r = np.clip(2.0 * s, 0.0, 1.0)
    g = np.clip(2.0 * (1.0 - s), 0.0, 1.0)
    return (np.stack([r, g, np.zeros_like(s)], axis=-1) * 255).astype(np.uint8)
