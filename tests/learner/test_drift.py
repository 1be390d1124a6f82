"""How much wider a model's intervals must be on a later day (``learner.carry.drift_scale``):
measured in batch training on the last hours of its own points, kept in its snapshot, and the
width a carry starts a new day with."""

import numpy as np
import pytest

from kinematics.errors import SnapshotError
from learner.carry import BEFORE_DAY, before_day, position_factor
from learner.config import ContinualConfig, TrainConfig
from learner.continual import ContinualLearner
from learner.continual_state import state_from_bytes, state_to_bytes
from learner.metrics import accuracy_report
from learner.snapshot import snapshot_from_bytes, snapshot_to_bytes
from learner.workflow import prepare, train_on_dataset
from tests.learner.conftest import make_dataset

DRIFT_M = 0.6e-3  # how far the robot's last points move, at most (m)


def _drifting(ds):
    """``ds`` whose last fifth in time moves as a link grows warm: up to 0.6 mm along x and z,
    more the further the arm reaches out (its second joint's angle)."""
    t = ds.table["t"].to_numpy(float)
    late = np.clip((t - np.quantile(t, 0.8)) / np.ptp(t) * 5.0, 0.0, None)
    reach = np.sin(ds.table["q2"].to_numpy(float))
    table = ds.table.copy()
    table["x"] += DRIFT_M * late * reach
    table["z"] -= DRIFT_M * late * reach
    return type(ds)(table=table, meta=ds.meta)


@pytest.fixture(scope="module")
def trained():
    """The same small network trained on a steady robot and on one that drifts at the end."""
    cfg = TrainConfig(max_epochs=150)
    ds = make_dataset(600, seed=3)
    return {
        name: train_on_dataset(data, seed=0, train_cfg=cfg, base="geometric")
        for name, data in (("steady", ds), ("drifting", _drifting(ds)))
    }


def test_training_measures_how_much_wider_a_later_day_needs_the_intervals(trained):
    steady, drifting = trained["steady"].model, trained["drifting"].model
    assert steady.drift_scale.shape == (6,) and steady.drift_scale.min() >= 1.0
    assert position_factor(steady.drift_scale) < 1.5
    x, y, z = drifting.drift_scale[:3]
    assert x > 2.0 and z > 2.0 and y < 1.5  # it moved along x and z, not y
    again = snapshot_from_bytes(snapshot_to_bytes(drifting))
    np.testing.assert_array_equal(again.drift_scale, drifting.drift_scale)


def test_no_drift_is_measured_at_fraction_zero_or_on_a_clock_that_never_moves():
    ds = make_dataset(300, seed=4)
    off = train_on_dataset(ds, train_cfg=TrainConfig(max_epochs=20, drift_fraction=0.0))
    np.testing.assert_array_equal(off.model.drift_scale, np.ones(6))
    still = type(ds)(table=ds.table.assign(t=0.0), meta=ds.meta)
    frozen = train_on_dataset(still, train_cfg=TrainConfig(max_epochs=20), base="geometric")
    np.testing.assert_array_equal(frozen.model.drift_scale, np.ones(6))


def test_a_carry_starts_the_day_as_wide_as_the_drift_says_and_trusts_it(trained):
    """The drifting robot's model carried to points recorded after all it learned, and moved
    as its last hours were: the intervals it came with cover fewer than the 85-95 % band asks
    (0.81 on an AMD EPYC with AVX-512), the drift-widened ones enough (0.96), and
    the day is not marked unverified for misses the drift explains."""
    result = trained["drifting"]
    model = result.model
    later = _drifting(make_dataset(600, seed=8))
    p = prepare(later, test_fraction=0.0, spec=model.spec)
    X, Y = p.X[480:], p.Y[480:]  # the last fifth: moved
    assert accuracy_report(model, X[20:], Y[20:]).coverage_90 < 0.85
    learner = ContinualLearner(snapshot_from_bytes(snapshot_to_bytes(model)), ContinualConfig())
    learner.carry(X[:20], Y[:20])
    np.testing.assert_allclose(
        learner.model.interval_scale, model.interval_scale * model.drift_scale
    )
    assert learner.model.unverified == ""
    assert accuracy_report(learner.model, X[20:], Y[20:]).coverage_90 > 0.85


def test_before_any_of_a_new_days_points_the_model_answers_drift_wide_and_unverified(trained):
    """Served on a later day before a carry has seen any of its points, the drifting robot's
    model covers that day as the drift-widened carry does, and says it is unchecked; the
    model it came from is left as it was."""
    model = trained["drifting"].model
    later = _drifting(make_dataset(600, seed=8))
    p = prepare(later, test_fraction=0.0, spec=model.spec)
    X, Y = p.X[480:], p.Y[480:]
    served = before_day(model)
    np.testing.assert_allclose(served.interval_scale, model.interval_scale * model.drift_scale)
    assert served.unverified == BEFORE_DAY and model.unverified == ""
    assert accuracy_report(model, X, Y).coverage_90 < 0.85
    assert accuracy_report(served, X, Y).coverage_90 > 0.85
    np.testing.assert_array_equal(served.predict(X).gamma, model.predict(X).gamma)
    again = snapshot_from_bytes(snapshot_to_bytes(served))
    assert again.unverified == BEFORE_DAY


def test_a_day_carried_again_while_young_is_not_widened_twice(trained):
    """A day saved before 20 of its points were held out and carried on into the next keeps
    the scale its first carry gave: the drift is allowed for once, not once a day."""
    model = trained["drifting"].model
    p = prepare(make_dataset(200, seed=9), test_fraction=0.0, spec=model.spec)
    learner = ContinualLearner(snapshot_from_bytes(snapshot_to_bytes(model)), ContinualConfig())
    learner.carry(p.X[:20], p.Y[:20])
    learner.update(p.X[20:120], p.Y[20:120])  # 10 of them held out: the day is young
    restarted = ContinualLearner(learner.model, ContinualConfig())
    restarted.load_state(state_from_bytes(state_to_bytes(learner.state_dict())))
    restarted.carry(p.X[120:140], p.Y[120:140])
    np.testing.assert_allclose(restarted.day_scale, learner.day_scale)
    fresh = ContinualLearner(snapshot_from_bytes(snapshot_to_bytes(model)), ContinualConfig())
    fresh.carry(p.X[120:140], p.Y[120:140])
    np.testing.assert_allclose(fresh.day_scale, model.interval_scale * model.drift_scale)


def test_a_snapshot_whose_drift_is_not_six_positive_factors_is_refused(trained):
    bad = snapshot_from_bytes(snapshot_to_bytes(trained["steady"].model))
    bad.drift_scale = np.array([1.0, 1.0, -2.0, 1.0, 1.0, 1.0])
    with pytest.raises(SnapshotError, match="drift_scale must be 6 positive factors"):
        snapshot_from_bytes(snapshot_to_bytes(bad))
