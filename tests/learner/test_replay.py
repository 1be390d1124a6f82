import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from kinematics.errors import ConfigError
from learner.replay import (
    REPLAY_STRATEGIES,
    FullReplay,
    MaxErrorReplay,
    NaiveReplay,
    ReservoirReplay,
    replay_strategy,
)


@settings(max_examples=60, deadline=None)
@given(
    st.lists(st.floats(0, 1e3, allow_nan=False), min_size=1, max_size=80),
    st.integers(1, 100),
)
def test_max_error_keeps_exactly_the_largest(errors, n_memory):
    errors = np.array(errors)
    keep = MaxErrorReplay().select(errors, n_memory, np.random.default_rng(0))
    assert len(keep) == min(n_memory, len(errors)) == len(set(keep.tolist()))
    dropped = np.setdiff1d(np.arange(len(errors)), keep)
    if dropped.size:
        assert errors[keep].min() >= errors[dropped].max()


@pytest.mark.parametrize("name", sorted(REPLAY_STRATEGIES))
def test_conformance(name):
    strategy = replay_strategy(name)
    errors = np.random.default_rng(1).uniform(size=30)
    keep = strategy.select(errors, 20, np.random.default_rng(0), n_new=10, n_seen=40)
    assert keep.dtype.kind == "i" and len(set(keep.tolist())) == len(keep)
    assert np.all((keep >= 0) & (keep < 30))
    again = strategy.select(errors, 20, np.random.default_rng(0), n_new=10, n_seen=40)
    np.testing.assert_array_equal(keep, again)


def test_baselines():
    errors = np.zeros(30)
    rng = np.random.default_rng(0)
    np.testing.assert_array_equal(NaiveReplay().select(errors, 5, rng, n_new=10), np.arange(20, 30))
    np.testing.assert_array_equal(FullReplay().select(errors, 5, rng, n_new=10), np.arange(30))


def test_reservoir_keeps_every_seen_point_equally_likely():
    rng = np.random.default_rng(0)
    counts = np.zeros(100)
    for _ in range(2000):
        memory = np.arange(0)
        for start in range(0, 100, 10):
            pool = np.concatenate([memory, np.arange(start, start + 10)])
            keep = ReservoirReplay().select(np.zeros(len(pool)), 20, rng, n_new=10, n_seen=start)
            memory = pool[keep]
        counts[memory] += 1
    freq = counts / 2000
    assert freq.mean() == pytest.approx(0.2)
    assert np.abs(freq - 0.2).max() < 0.05


def test_unknown_strategy():
    with pytest.raises(ConfigError, match="lru"):
        replay_strategy("lru")
