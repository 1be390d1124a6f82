import numpy as np
import pytest

from learner.config import ModelConfig, TrainConfig
from learner.features import FeatureSpec
from learner.metrics import ARCMIN_PER_RAD, AccuracyReport, accuracy_report, trust
from learner.model import ErrorModel

SPEC = FeatureSpec(names=("q1",), low=np.array([-1.0]), high=np.array([1.0]))


@pytest.fixture(scope="module")
def fitted():
    rng = np.random.default_rng(0)
    X = rng.uniform(-1, 1, (300, 1))
    Y = X * np.array([2e-3, 1e-4, 1e-4, 1e-3, 0.0, 5e-4]) + rng.normal(0, 5e-5, (300, 6))
    m = ErrorModel.create(
        SPEC,
        ModelConfig(hidden_layers=1, neurons=16, encoding="minmax"),
        TrainConfig(max_epochs=60),
        0,
    )
    m.fit(X[:200], Y[:200])
    return m, X[200:], Y[200:]


def test_report_keys_and_values_match_a_direct_computation(fitted):
    m, X, Y = fitted
    r = accuracy_report(m, X, Y)
    assert tuple(r.to_dict()) == AccuracyReport.KEYS  # the keys: tests/kinematics/test_error_stats
    res = Y - m.predict(X).gamma
    pos = np.linalg.norm(res[:, :3], axis=1) * 1e3
    assert r.mean_mm == pytest.approx(pos.mean()) and r.max_mm == pytest.approx(pos.max())
    assert r.std_mm == pytest.approx(pos.std(ddof=1))  # the sample std (ErrorStats)
    rot = np.linalg.norm(res[:, 3:], axis=1) * ARCMIN_PER_RAD
    assert r.mean_arcmin == pytest.approx(rot.mean())
    base = np.linalg.norm(Y[:, :3], axis=1).mean() * 1e3
    assert r.improvement_pct == pytest.approx(100 * (1 - pos.mean() / base))
    assert 0 <= r.coverage_68 <= r.coverage_90 <= r.coverage_95 <= 1
    assert r.interval_width_90_mm > 0 and np.isfinite(r.nll)


def test_uncalibrated_baseline_is_used(fitted):
    m, X, Y = fitted
    r = accuracy_report(m, X, Y, Y_uncalibrated=2 * Y)
    assert r.uncalibrated_mean_mm == pytest.approx(
        2 * np.linalg.norm(Y[:, :3], axis=1).mean() * 1e3
    )


def test_nll_is_in_mm(fitted):
    m, X, Y = fitted
    r = accuracy_report(m, X, Y)
    nll_m = m.predict(X).nll(Y)[:, :3].mean()
    assert r.nll == pytest.approx(nll_m + np.log(1e3))


def test_trust_flags_rows_as_compensation_does(fitted):
    """Over the epistemic limit, past the angles trained on, or every row of an unverified
    model: each flag alone makes a row untrusted."""
    m, X, _ = fitted
    assert not trust(m, X, epistemic_limit_mm=1e3).untrusted.any()
    tight = trust(m, X, epistemic_limit_mm=0.0)
    assert tight.over_epistemic_limit.all() and not tight.past_envelope.any()
    far = trust(m, X + 3.0, epistemic_limit_mm=1e3)  # q1 beyond -1..1 rad by 2 rad or more
    assert far.past_envelope.all() and far.untrusted.all()
    m.unverified = "the frames moved on this day (30 points)"
    try:
        flags = trust(m, X, epistemic_limit_mm=1e3)
    finally:
        m.unverified = ""
    assert flags.unverified and flags.untrusted.all() and not flags.past_envelope.any()
