"""A carried day's frames fitted again as its points come (``learner.carry.CarriedDay``,
``ContinualLearner.carry`` / ``update``): the first points of one side, sharing a local error,
fold it into the frames; all of the day's points spread it out."""

from dataclasses import replace

import numpy as np
import pytest

from kinematics.errors import ConfigError
from kinematics.model import RobotModel
from learner.base import identify_base
from learner.carry import CarriedDay, reidentify_frames, spread
from learner.config import ContinualConfig, ModelConfig, TrainConfig
from learner.continual import MIN_DAY_POINTS, ContinualLearner
from learner.continual_state import state_from_bytes, state_to_bytes
from learner.model import ErrorModel
from learner.snapshot import snapshot_from_bytes, snapshot_to_bytes
from learner.workflow import prepare
from tests.learner.conftest import make_dataset
from tests.learner.test_base import _frame, _moved

CFG = ContinualConfig(memory=300, batch=50, holdout=0.2, epochs_per_update=10)


@pytest.fixture(scope="module")
def day():
    """A model (geometric base + network) of 200 points; the next day, its tracker moved by
    2 mm / 2 mrad and the tool by 1 mm / 1 mrad, in stream order: 30 points of one side (the
    smallest q1) that share a 0.4 mm error along x (a cold start), then 270 of the rest."""
    p = prepare(make_dataset(500, seed=3), test_fraction=0.0)
    base = identify_base("geometric", p.spec, p.X[:200], p.Y[:200])
    model = ErrorModel.create(
        p.spec, ModelConfig(hidden_layers=2, neurons=32), TrainConfig(max_epochs=100), 0, base=base
    )
    model.fit(p.X[:200], p.Y[:200])
    Y2 = _moved(p, _frame([2e-3, -1e-3, 0.5e-3], 2e-3), _frame([0, 1e-3, 0], 1e-3))
    later = np.arange(200, 500)
    order = later[np.argsort(p.X[later, 0])]
    order = np.concatenate([order[:30], np.random.default_rng(0).permutation(order[30:])])
    X, truth = p.X[order], Y2[order]
    Y = truth.copy()
    Y[:30, 0] += 0.4e-3
    return p, model, X, Y, truth


def _frames_mm(base, model, p, X, truth) -> float:
    """How far (mean position, mm, over the day) ``base`` is from the frames that all of the
    day's points give without the cold error (least squares, ``model``'s network taken off)."""
    nominal = RobotModel(p.spec.description)
    best = reidentify_frames(model.base, p.spec, X, truth, residual=model.residual(X), prior_m=None)
    off = base.error(p.spec, X, nominal) - best.error(p.spec, X, nominal)
    return float(np.linalg.norm(off[:, :3], axis=1).mean() * 1e3)


def _carried(model, X, Y, memory=None) -> ContinualLearner:
    learner = ContinualLearner(snapshot_from_bytes(snapshot_to_bytes(model)), CFG)
    if memory is not None:  # the day before's points, as a model's state beside it keeps them
        learner.remember(*memory)
    learner.carry(X[:30], Y[:30])
    return learner


def test_the_days_frames_are_fitted_again_as_its_points_double(day):
    p, model, X, Y, truth = day
    learner = _carried(model, X, Y)
    assert learner.day.fitted == 30 and len(learner.day.x) == 0
    carried = _frames_mm(learner.base, model, p, X, truth)
    fits = []
    for i in range(0, len(X), 50):
        learner.update(X[i : i + 50], Y[i : i + 50])
        fits.append(learner.day.fitted)
    assert fits == [30, 80, 80, 160, 160, 160]  # 40 of each 50 trained, fitted at 2 x
    assert "frames moved on 160 new points" in learner.base.note
    assert learner.base.note.count("frames") == 1  # each fit from the frames carried from
    assert _frames_mm(learner.base, model, p, X, truth) < 0.5 * carried


def test_the_days_points_keep_their_labels_and_the_old_ones_their_residual(day):
    p, model, X, Y, truth = day
    learner = _carried(model, X, Y, memory=(p.X[:200], p.Y[:200]))
    learner.update(X[:50], Y[:50])
    before = learner.memory
    old = ~learner.day.holds(before.x)
    residual = before.y[old] - learner.trained.base_error(before.x[old])
    learner.update(X[50:100], Y[50:100])  # 80 trained points: fitted again
    assert learner.day.fitted == 80
    after = learner.memory
    still = learner.day.holds(after.x)
    rows = {r.tobytes(): i for i, r in enumerate(X)}
    np.testing.assert_array_equal(after.y[still], Y[[rows[r.tobytes()] for r in after.x[still]]])
    kept = {r.tobytes(): i for i, r in enumerate(before.x[old])}
    back = [kept[r.tobytes()] for r in after.x[~still]]
    assert len(back) > 100
    now = after.y[~still] - learner.trained.base_error(after.x[~still])
    np.testing.assert_allclose(now, residual[back], atol=1e-12)
    assert not np.allclose(after.y[~still], before.y[old][back])


def test_the_day_survives_a_restart(day):
    p, model, X, Y, _ = day
    learner = _carried(model, X, Y, memory=(p.X[:200], p.Y[:200]))
    for i in range(0, 100, 50):
        learner.update(X[i : i + 50], Y[i : i + 50])
    state = state_from_bytes(state_to_bytes(learner.state_dict()))
    restarted = ContinualLearner(snapshot_from_bytes(snapshot_to_bytes(model)), CFG)
    restarted.load_state(state)
    for got, want in ((restarted.day, learner.day),):
        np.testing.assert_array_equal(got.x, want.x)
        np.testing.assert_array_equal(got.source_frames, want.source_frames)
        assert (got.fitted, got.source_note) == (want.fitted, want.source_note)
        assert got.seen_before == want.seen_before == 200
    for a in (learner, restarted):
        a.update(X[100:150], Y[100:150])
    np.testing.assert_array_equal(restarted.base.T_0_B, learner.base.T_0_B)
    uncarried = ContinualLearner(snapshot_from_bytes(snapshot_to_bytes(model)), CFG)
    assert "day_x" not in uncarried.state_dict() and uncarried.day is None


def test_a_day_adds_points_up_to_its_limit_and_is_fitted_there_once(day):
    p, model, _, _, _ = day
    d = CarriedDay.start(model.base, 30, p.spec.n_features)
    X, Y = np.zeros((100, p.spec.n_features)), np.zeros((100, 6))
    d = d.add(X[:29], Y[:29], 80)
    assert not d.due(80)
    d = d.add(X[:31], Y[:31], 80)
    assert d.due(80) and len(d.x) == 60
    d = replace(d, fitted=60).add(X, Y, 80)
    assert len(d.x) == 80 and d.due(80)
    d = replace(d, fitted=80)
    assert not d.add(X, Y, 80).due(80) and len(d.add(X, Y, 80).x) == 80


def test_a_day_limit_of_0_keeps_the_first_points_frames(day):
    p, model, X, Y, _ = day
    learner = ContinualLearner(
        snapshot_from_bytes(snapshot_to_bytes(model)), replace(CFG, day_frame_points=0)
    )
    learner.carry(X[:30], Y[:30])
    carried = learner.base
    for i in range(0, 200, 50):
        learner.update(X[i : i + 50], Y[i : i + 50])
    assert learner.base is carried and len(learner.day.x) == 0
    with pytest.raises(ConfigError, match="day_frame_points"):
        ContinualConfig(day_frame_points=-1)


def test_a_day_whose_frames_moved_is_unverified_until_its_own_points_check_it(day):
    """The carry's scale comes from the day's first points of one side; compensation is not to
    trust it (``ErrorModel.unverified``, in the snapshot) until at least ``MIN_DAY_POINTS`` of
    the day's points, spread over the workspace, are held out and calibrate it. A day whose
    frames held is verified from the start."""
    p, model, X, Y, _ = day
    learner = _carried(model, X, Y)
    assert learner.model.unverified.startswith("the frames moved on this day (30 points)")
    assert snapshot_from_bytes(snapshot_to_bytes(learner.model)).unverified == (
        learner.model.unverified
    )
    learner.update(X[:50], Y[:50])  # 10 of the day's points held out
    assert learner.model.unverified
    learner.update(X[50:100], Y[50:100])
    assert len(learner.state_dict()["holdout_x"]) == MIN_DAY_POINTS
    assert learner.model.unverified  # 20 points cannot identify the geometry: not spread yet
    for i in range(100, 300, 50):
        learner.update(X[i : i + 50], Y[i : i + 50])
    state = learner.state_dict()
    assert spread(p.spec, state["holdout_x"], state["holdout_y"])
    assert learner.model.unverified == ""
    assert snapshot_from_bytes(snapshot_to_bytes(learner.model)).unverified == ""
    same_day = ContinualLearner(snapshot_from_bytes(snapshot_to_bytes(model)), CFG)
    same_day.carry(p.X[200:230], p.Y[200:230])
    assert "frames held" in same_day.base.note and same_day.model.unverified == ""
