"""Adaptive conformal inference (Gibbs & Candès 2021) on an interval scale, point by point.

The held-out calibration makes a model's intervals honest where its held-out points lie; a
stream that moves (a new day, an unseen region) needs more. ACI widens the intervals after each
point that falls outside them and narrows them after each inside, so that on the stream the
share outside tends to ``1 - level`` whatever the shift.

>>> import numpy as np
>>> misses = np.full((100, 1), 3.0)  # a batch 3 half-widths off: intervals far too narrow
>>> s = adapt_log_scale(np.zeros(1), misses, rate=0.05, level=0.9)
>>> round(float(np.exp(s[0])), 1)  # until they fall inside; one step for all: e^(0.05 x 90)
3.0
"""

import numpy as np

#: Bounds of the log scale: ACI never narrows the intervals below what the held-out points
#: calibrate (it widens them where the stream shows they are too narrow), and widens them by
#: at most e^3 = 20 x.
LOG_SCALE_BOUNDS = (0.0, 3.0)


def adapt_log_scale(
    log_scale: np.ndarray, excess: np.ndarray, rate: float, level: float
) -> np.ndarray:
    """The log interval scale after the batch's points, taken one at a time in stream order.

    ``excess`` (n, c) is each point's distance from its interval's centre in half-widths of its
    ``level`` interval at ``log_scale`` (> 1: outside). Each point is scored at the scale the
    points before it left, as ACI on a point stream does: a batch scored at one scale would move
    it by ``rate`` × n × the miss share at once and overshoot (n 100: about 1.5 × the error)."""
    s = np.asarray(log_scale, dtype=float).copy()
    for e in np.asarray(excess, dtype=float):
        miss = e > np.exp(s - log_scale)
        s = np.clip(s + rate * (miss - (1.0 - level)), *LOG_SCALE_BOUNDS)
    return s


def take_up(log_scale: np.ndarray, last: np.ndarray, scale: np.ndarray) -> np.ndarray:
    """The log scale after the calibrated scale went from ``last`` to ``scale``, the published
    one (``last`` × e^``log_scale``) kept: a new calibration narrows nothing at once (ACI narrows
    as the next points fall inside) and widens only past what is published. A carried day
    calibrated on its first 20-40 held-out points was too narrow for its next batch; taking up
    only the narrowing would stack each calibration's jitter up into ever wider intervals.

    >>> one, two = np.ones(2), np.array([2.0, 2.0])
    >>> s = take_up(np.zeros(2), last=two, scale=one)  # halved: ACI doubles it
    >>> np.exp(s).tolist()
    [2.0, 2.0]
    >>> s = take_up(s, last=one, scale=np.array([1.5, 4.0]))  # 1.5: the published 2 kept; 4 past it
    >>> np.round(np.exp(s), 2).tolist()
    [1.33, 1.0]
    """
    return np.clip(log_scale + np.log(np.asarray(last) / scale), *LOG_SCALE_BOUNDS)
