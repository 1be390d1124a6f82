"""Adaptive conformal inference on the interval scale: point by point, never below calibration."""

import numpy as np
from scipy import stats

from learner.conformal import adapt_log_scale

Z90 = stats.norm.ppf(0.95)


def excess(rng: np.random.Generator, n: int, sigma: float) -> np.ndarray:
    """Distances from the centre, in half-widths of a 90 % interval calibrated for sigma 1."""
    return np.abs(rng.normal(0.0, sigma, (n, 3))) / Z90


def test_one_batch_of_misses_widens_to_what_it_shows_without_overshooting() -> None:
    rng = np.random.default_rng(0)
    s = adapt_log_scale(np.zeros(3), excess(rng, 100, 2.0), rate=0.05, level=0.9)
    # Intervals twice too narrow: 41 % of the batch is outside. Scored at one scale the batch
    # would widen them 4.7 x (0.05 x (41 - 10)); point by point they stop near 2 x.
    assert np.all((np.exp(s) > 1.4) & (np.exp(s) < 2.8)), np.exp(s)
    next_batch = excess(rng, 2000, 2.0)
    coverage = np.mean(next_batch <= np.exp(s), axis=0)
    assert np.all((coverage > 0.8) & (coverage < 0.97)), coverage


def test_never_narrower_than_the_calibration() -> None:
    inside = np.zeros((200, 3))  # every point dead centre
    assert np.all(adapt_log_scale(np.zeros(3), inside, rate=0.05, level=0.9) == 0.0)
    wide = np.full(3, 1.0)  # widened before; now the stream is calm again
    s = adapt_log_scale(wide, inside, rate=0.05, level=0.9)
    assert np.all(s < wide) and np.all(s >= 0.0)


def test_share_outside_holds_through_a_shift() -> None:
    rng = np.random.default_rng(1)
    stream = np.concatenate([excess(rng, 500, 1.0), excess(rng, 2500, 3.0)])
    s, misses = np.zeros(3), []
    for batch in np.split(stream, 30):  # batches of 100, each scored at the scale before it
        misses.append(batch > np.exp(s))
        s = adapt_log_scale(s, batch / np.exp(s), rate=0.05, level=0.9)
    share = np.mean(np.concatenate(misses), axis=0)
    assert np.all((share > 0.07) & (share < 0.13)), share
    assert np.all((np.exp(s) > 2.2) & (np.exp(s) < 4.0)), np.exp(s)
