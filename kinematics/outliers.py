"""Gross outliers of a measured series: rows no robot error explains.

A tracker that lost its beam, a swapped reflector or a mistyped row puts a measured pose metres
or tens of millimetres from where the series' other points say the robot's error lies, and one
such row sways a least-squares fit: a single row 1 m off in UR10 Series B's 1,495 took
``robocal calibrate``'s mean error on the other rows from 0.40 to 1.20 mm. A row is a gross
outlier when its pose error against the nominal model lies more than ``GROSS_THRESHOLD`` robust
units from the series' own errors (:func:`robust_distance`); clean series reach 4-12 (UR10 A
and B, the paper campaign, twenty random arms). The stream's quarantine judges a point before
its first model by the same measure and number (:mod:`learner.quarantine`). When more than
``MAX_GROSS_SHARE`` of the rows are that far, they are a change of set-up within the file, not
faults, and none is an outlier; one row alone always is (a lost beam among a carried day's first
10 points is a fault, not a new set-up).

>>> rng = np.random.default_rng(0)
>>> errors = rng.normal(scale=1e-3, size=(200, 6))  # m and rad
>>> errors[13, 0] = 10.0  # a lost beam: 10 m off
>>> gross_outliers(errors).tolist()
[13]
"""

from __future__ import annotations

import numpy as np

#: Normal-consistency factor of the median absolute deviation.
MAD_TO_STD = 1.4826
#: Robust units (normal-scaled MADs, norm over the six components) past which a row is gross.
GROSS_THRESHOLD = 100.0
#: More than this share of rows past the threshold is a change of set-up: nothing is dropped.
MAX_GROSS_SHARE = 0.05
#: The least spread (m, rad) a robust unit stands for: about a laser tracker's noise (10 µm, 2
#: arcsec). Errors spread less (an exact simulation) are as alike as a tracker can tell them.
TRACKER_NOISE = 1e-5


def robust_distance(r: np.ndarray, reference: np.ndarray, floor: float = 1e-12) -> np.ndarray:
    """Per row of ``r`` (N, k), the Euclidean norm over components of its distance to the
    median of ``reference`` (R, k) in units of the reference's normal-scaled MAD (at least
    ``floor``, in the components' units)."""
    center = np.median(reference, axis=0)
    spread = MAD_TO_STD * np.median(np.abs(reference - center), axis=0)
    return np.linalg.norm((r - center) / np.maximum(spread, floor), axis=1)


def gross_outliers(errors: np.ndarray, threshold: float = GROSS_THRESHOLD) -> np.ndarray:
    """Rows of ``errors`` (N, k; m and rad) more than ``threshold`` robust units from the
    series' own, a spread below ``TRACKER_NOISE`` counted as that; none when more than
    ``MAX_GROSS_SHARE`` of the rows (and more than one) are."""
    far = np.flatnonzero(robust_distance(errors, errors, TRACKER_NOISE) > threshold)
    return far if len(far) <= max(1.0, MAX_GROSS_SHARE * len(errors)) else far[:0]


def without_gross_rows(X: np.ndarray, Y: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``X, Y`` without the rows whose errors ``Y`` are gross outliers (:func:`gross_outliers`)."""
    keep = np.setdiff1d(np.arange(len(Y)), gross_outliers(Y))
    return X[keep], Y[keep]
