"""Re-identified frames keep their posterior spread, and the model's intervals carry it: frames
fixed by a few points of one corner are known there and poorly far from it
(:func:`learner.carry.frame_sigma_points`, :meth:`learner.base.PhysicsBase.frame_variance`)."""

from dataclasses import replace

import numpy as np
import pytest

from kinematics.model import RobotModel
from learner.base import identify_base
from learner.carry import reidentify_frames
from learner.config import ModelConfig, TrainConfig
from learner.model import ErrorModel
from learner.snapshot import snapshot_from_bytes, snapshot_to_bytes
from learner.workflow import prepare
from tests.learner.conftest import make_dataset
from tests.learner.test_base import _frame, _moved


@pytest.fixture(scope="module")
def day():
    """A day whose tracker moved by 2 mm / 2 mrad and tool by 1 mm / 1 mrad, its base from
    the day before, and its 12 points of smallest q1 (one side of the robot)."""
    p = prepare(make_dataset(300, seed=3), test_fraction=0.0)
    base = identify_base("geometric", p.spec, p.X[:200], p.Y[:200])
    Y2 = _moved(p, _frame([2e-3, -1e-3, 0.5e-3], 2e-3), _frame([0, 1e-3, 0], 1e-3))
    return p, base, Y2, np.argsort(p.X[:, 0])[:12]


def _std_mm(base, p, rows) -> float:
    variance = base.frame_variance(p.spec, p.X[rows], RobotModel(p.spec.description))
    return float(np.sqrt(variance[:, :3].sum(axis=1)).mean() * 1e3)


def test_frames_from_one_side_are_known_there_and_less_on_the_other(day):
    """12 points of one side against 100 spread ones: wider on the other side (its 50 points
    of largest q1; 0.87 against 0.64 mm here) and about 3 x wider than from 100 points."""
    p, base, Y2, side = day
    far = np.argsort(p.X[:, 0])[-50:]
    local = reidentify_frames(base, p.spec, p.X[side], Y2[side], prior_m=3e-4)
    spread = reidentify_frames(base, p.spec, p.X[::3], Y2[::3], prior_m=3e-4)
    assert local.frame_sigma.shape[1:] == (2, 4, 4) and len(local.frame_sigma) <= 12
    assert base.frame_sigma is None and _std_mm(base, p, far) == 0.0
    assert _std_mm(local, p, far) > 1.2 * _std_mm(local, p, side)
    assert _std_mm(spread, p, far) < 0.5 * _std_mm(local, p, far)


def test_the_spread_widens_the_models_intervals_and_survives_its_snapshot(day):
    p, base, Y2, corner = day
    local = reidentify_frames(base, p.spec, p.X[corner], Y2[corner], prior_m=3e-4)
    cfg = ModelConfig(hidden_layers=1, neurons=8)
    model = ErrorModel.create(p.spec, cfg, TrainConfig(), seed=0, base=local)
    model.fit(p.X[:100], Y2[:100], max_epochs=3)
    with_spread = model.predict(p.X)
    reloaded = snapshot_from_bytes(snapshot_to_bytes(model))
    np.testing.assert_array_equal(reloaded.base.frame_sigma, local.frame_sigma)
    np.testing.assert_array_equal(reloaded.predict(p.X).beta, with_spread.beta)
    model.base = replace(local, frame_sigma=None)
    without = model.predict(p.X)
    np.testing.assert_array_equal(without.gamma, with_spread.gamma)
    width = np.subtract(*with_spread.interval(0.9)[::-1])[:, :3]
    narrower = np.subtract(*without.interval(0.9)[::-1])[:, :3]
    assert np.all(width >= narrower) and np.mean(width / narrower) > 1.05
