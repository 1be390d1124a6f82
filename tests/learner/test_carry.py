"""A model carried into a new day: the network weighed by what the day's points show
(``ErrorModel.weigh_residual``, ``ContinualLearner.carry``)."""

import numpy as np
import pytest

from learner.carry import MISS_EVIDENCE, position_factor, spread
from learner.config import ContinualConfig, ModelConfig, TrainConfig
from learner.continual import MIN_DAY_POINTS, ContinualLearner
from learner.continual_state import state_from_bytes, state_to_bytes
from learner.metrics import accuracy_report
from learner.model import ErrorModel
from learner.snapshot import snapshot_from_bytes, snapshot_to_bytes
from learner.workflow import prepare
from tests.learner.conftest import make_dataset


def _position_mm(model, X, Y):
    return float(np.linalg.norm((model.predict(X).gamma - Y)[:, :3], axis=1).mean() * 1e3)


@pytest.fixture(scope="module")
def learned():
    """A small network trained on 200 points of the perturbed Fanuc (nominal base), and 200
    more points of the same robot."""
    p = prepare(make_dataset(400, seed=5), test_fraction=0.0)
    model = ErrorModel.create(
        p.spec, ModelConfig(hidden_layers=2, neurons=32), TrainConfig(max_epochs=150), seed=0
    )
    model.fit(p.X[:200], p.Y[:200])
    return p, model


def _copy(model):
    return snapshot_from_bytes(snapshot_to_bytes(model))


def test_the_gain_keeps_a_network_that_explains_the_day_and_drops_one_that_does_not(learned):
    p, model = learned
    X, Y = p.X[200:], p.Y[200:]
    same = _copy(model)
    assert same.weigh_residual(X, Y) > 0.8
    other = _copy(model)
    day = Y - 0.8 * other.residual(X)  # another day: most of what the network learned is gone
    before = _position_mm(other, X, day)
    gain = other.weigh_residual(X, day)
    assert 0.1 < gain < 0.35
    assert _position_mm(other, X, day) < 0.7 * before
    other.residual_gain = 0.0
    np.testing.assert_allclose(other.predict(X).gamma, other.base_error(X))


def test_the_gain_travels_in_the_snapshot(learned):
    _, model = learned
    m = _copy(model)
    m.residual_gain = 0.25
    assert snapshot_from_bytes(snapshot_to_bytes(m)).residual_gain == 0.25
    assert model.residual_gain == 1.0


def test_a_carried_learner_weighs_its_network_then_learns_the_day_back(learned):
    """The day's residual is the opposite of what the network learned: the gain drops to 0 at
    the carry, and comes back once updates on the day's points have taught the network."""
    p, model = learned
    X, Y = p.X[200:], p.Y[200:] - 2.0 * model.residual(p.X[200:])
    cfg = ContinualConfig(memory=150, batch=50, holdout=0.2, epochs_per_update=40, update_lr=3e-3)
    learner = ContinualLearner(_copy(model), cfg)
    gain = learner.carry(X[:50], Y[:50])
    assert gain == 0.0 and learner.model.residual_gain == 0.0
    state = state_from_bytes(state_to_bytes(learner.state_dict()))
    assert "day_scale" in state and len(state["holdout_x"]) == 0
    gains = []
    for i in range(0, 200, 50):
        learner.update(X[i : i + 50], Y[i : i + 50])
        gains.append(learner.model.residual_gain)
    assert len(learner.state_dict()["holdout_x"]) >= MIN_DAY_POINTS
    assert gains[0] == 0.0  # 10 held-out points: the carry's gain stands
    assert gains[-1] > 0.5
    restarted = ContinualLearner(_copy(model), cfg)
    restarted.load_state(state_from_bytes(state_to_bytes(learner.state_dict())))
    assert restarted.day_scale is not None and restarted.model.residual_gain == gains[-1]


def test_a_day_whose_points_the_intervals_miss_is_widened_and_unverified(learned):
    """The frames held, but on this day a third of what the network learned is gone: the
    intervals the model came with miss the day's first points (44 % covered), so the carry
    widens them to what those points need and marks the day unverified. The same robot's next
    points need about the scale it came with and are carried as they were."""
    p, model = learned
    X, Y = p.X[200:], p.Y[200:]
    same = ContinualLearner(_copy(model), ContinualConfig())
    same.carry(X[:25], Y[:25])
    assert same.model.unverified == "" and "frames held" in same.base.note
    np.testing.assert_array_equal(same.day_scale, model.interval_scale)
    day = Y - 0.3 * model.residual(X)
    assert accuracy_report(model, X[25:], day[25:]).coverage_90 < 0.5
    other = ContinualLearner(_copy(model), ContinualConfig())
    other.carry(X[:25], day[:25])
    assert "frames held" in other.base.note
    assert other.model.unverified.startswith("the intervals it came with were ")
    assert "x too narrow on this day (25 points)" in other.model.unverified
    widened = other.model.interval_scale / model.interval_scale
    assert widened.min() >= 1.0 - 1e-12 and position_factor(widened) > MISS_EVIDENCE
    assert accuracy_report(other.model, X[25:], day[25:]).coverage_90 > 0.85
    state = state_from_bytes(state_to_bytes(other.state_dict()))
    np.testing.assert_allclose(state["day_scale"], other.day_scale)


def test_an_uncarried_learner_never_touches_the_gain(learned):
    p, model = learned
    learner = ContinualLearner(_copy(model), ContinualConfig(batch=50, holdout=0.5))
    for i in range(200, 400, 50):
        learner.update(p.X[i : i + 50], p.Y[i : i + 50])
    assert learner.day_scale is None and learner.model.residual_gain == 1.0


def test_a_marked_day_stays_unverified_while_its_held_out_points_lie_in_one_region(learned):
    """A day whose error is far from what the network learned is marked at its carry. At one
    base angle (q1 over 0.3 deg) its held-out points cannot check the intervals elsewhere:
    after every update the mark stays, also when a fresh network (which starts unmarked) is
    kept. A day spread over the workspace clears it once its held-out points identify the
    geometry."""
    p, model = learned
    cfg = ContinualConfig(batch=50, holdout=0.5, epochs_per_update=20, init_epochs=60)
    region = prepare(make_dataset(175, seed=7, q1_range=(0.3, 0.305)), test_fraction=0.0)
    days = {"region": (region.X, region.Y), "spread": (p.X[200:], p.Y[200:])}
    for name, (X, Y) in days.items():
        Y = Y - 2.0 * model.residual(X)
        learner = ContinualLearner(_copy(model), cfg)
        learner.carry(X[:25], Y[:25])
        mark, fresh = learner.model.unverified, 0
        assert mark.startswith("the intervals it came with were "), name
        for i in range(25, 175, 50):
            trained = learner.trained
            learner.update(X[i : i + 50], Y[i : i + 50])
            fresh += learner.trained is not trained  # a fresh network was kept
            if name == "region":
                assert learner.model.unverified == mark
        assert fresh >= 1, name
        state = learner.state_dict()
        assert len(state["holdout_x"]) >= 3 * MIN_DAY_POINTS
        assert spread(model.spec, state["holdout_x"], state["holdout_y"]) == (name == "spread")
    assert learner.model.unverified == ""  # the spread day, checked by its own points


def test_a_days_calibration_narrower_than_its_scale_narrows_it_only_as_its_points_allow(learned):
    """Carried with intervals three times too wide, the day's first calibration (20 held-out
    points) is far narrower: the published scale does not fall to it at once (ACI takes the
    difference up), and narrows as the day's next points fall inside it."""
    p, model = learned
    wide = _copy(model)
    wide.interval_scale = 3.0 * wide.interval_scale
    cfg = ContinualConfig(memory=150, batch=50, holdout=0.2, epochs_per_update=5, seed=0)
    learner = ContinualLearner(wide, cfg)
    learner.carry(p.X[200:250], p.Y[200:250])
    published = [learner.model.interval_scale.copy()]
    for i in range(200, 400, 50):
        learner.update(p.X[i : i + 50], p.Y[i : i + 50])
        published.append(learner.model.interval_scale.copy())
    # 10, 20, 30, 40 held-out points: the day's own calibration from the second update on
    calibrated = learner.day_scale
    assert np.all(calibrated < 0.6 * published[0])
    np.testing.assert_allclose(
        learner.model.interval_scale, calibrated * np.exp(learner.aci_log_scale)
    )
    assert np.all(published[2] > 0.8 * published[1])  # not at once
    assert position_factor(published[-1] / published[0]) < 0.9  # but as the points show
    state = state_from_bytes(state_to_bytes(learner.state_dict()))
    np.testing.assert_allclose(state["day_scale"], calibrated)
