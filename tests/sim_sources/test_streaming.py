"""The simulated cell as a sample stream: rates, settling, order, pacing."""

import numpy as np
import pytest

from kinematics.errors import ConfigError
from sim_sources.cell import simulate
from sim_sources.scenarios import get_scenario
from sim_sources.streaming import StreamingConfig, cell_samples, min_jerk, paced
from wire import JointSample, TemperatureSample, TrackerSample


@pytest.fixture(scope="module")
def ds():
    return simulate(get_scenario("paper"), 6, 0)


def test_rates_order_and_settled_measurements(ds):
    cfg = StreamingConfig(period_s=2.0)
    samples = list(cell_samples(ds, cfg))
    t = np.array([s.t for s in samples])
    assert np.all(np.diff(t) >= 0)
    joints = [s for s in samples if isinstance(s, JointSample)]
    tracker = [s for s in samples if isinstance(s, TrackerSample)]
    temps = [s for s in samples if isinstance(s, TemperatureSample)]
    assert [s.seq for s in joints] == list(range(len(joints)))
    np.testing.assert_allclose(np.diff([s.t for s in joints]), 1 / 125, atol=1e-9)
    np.testing.assert_allclose(np.diff([s.t for s in temps]), 1.0, atol=1e-9)
    assert len(tracker) == 6 and tracker[0].frame == "tracker"
    assert len(temps[0].names) == 15
    jt = np.array([s.t for s in joints])
    jq = np.array([s.q for s in joints])
    for k, tk in enumerate(tracker):
        near = (jt >= tk.t - 0.9 * cfg.settle_s) & (jt <= tk.t + 0.9 * cfg.dwell_s)
        np.testing.assert_allclose(jq[near], ds.q()[k][None].repeat(near.sum(), 0), atol=1e-12)
        row = ds.table.iloc[k]
        assert tk.xyz == (row.x, row.y, row.z)
    qs = np.array([s.qs for s in joints])
    assert np.all(np.abs(qs - jq) < 0.01)


def test_min_jerk_is_smooth_and_clipped():
    s = np.array([-1.0, 0.0, 0.5, 1.0, 2.0])
    np.testing.assert_allclose(min_jerk(s), [0.0, 0.0, 0.5, 1.0, 1.0])


def test_paced_follows_source_time():
    now = [0.0]
    slept = []

    def sleep(dt):
        slept.append(dt)
        now[0] += dt

    samples = [JointSample(seq=i, t=10.0 + i, q=(0.0,)) for i in range(3)]
    out = list(paced(samples, speed=2.0, clock=lambda: now[0], sleep=sleep))
    assert out == samples and slept == [0.5, 0.5]
    assert list(paced(samples, None)) == samples


def test_visits_too_close_need_a_period(ds):
    with pytest.raises(ConfigError, match="period_s"):
        StreamingConfig(period_s=0.5)
