"""A continual learner identifies its physics base again from its replay memory."""

import numpy as np
import pytest

from kinematics.model import RobotModel
from learner.base import identify_base, nominal_base
from learner.config import ContinualConfig, ModelConfig, TrainConfig
from learner.continual import ContinualLearner
from learner.continual_base import FIRST_REIDENTIFY, due, memory_base, scheduled, status
from learner.model import ErrorModel
from learner.workflow import prepare
from tests.learner.conftest import make_dataset


@pytest.fixture(scope="module")
def corner_first():
    """40 points with q1 in a narrow band, then 360 over the whole range (a real stream)."""
    corner = prepare(make_dataset(40, seed=1, q1_range=(-0.2, 0.2)), test_fraction=0.0)
    rest = prepare(make_dataset(560, seed=2), test_fraction=0.0)
    X = np.concatenate([corner.X, rest.X[:360]])
    Y = np.concatenate([corner.Y, rest.Y[:360]])
    return corner.spec, X, Y, rest.X[360:], rest.Y[360:]


def _base_mm(base, spec, X, Y) -> float:
    E = Y - base.error(spec, X, RobotModel(spec.description))
    return float(np.linalg.norm(E[:, :3], axis=1).mean() * 1e3)


def test_the_schedule_and_which_bases_are_identified_again(corner_first):
    spec, X, Y, _, _ = corner_first
    geometric = identify_base("geometric", spec, X[:40], Y[:40])
    assert status(geometric) == "identified"
    assert status(identify_base("auto", spec, X[:5], Y[:5])) == "nominal"
    assert status(nominal_base(spec.description)) == "fixed"
    assert geometric.condition == pytest.approx(68.6, abs=0.05)  # the corner: weakly identified
    assert [v for v in range(70) if due(v, geometric)] == [FIRST_REIDENTIFY]
    assert not any(scheduled(v, "identified", 10.7) for v in range(70))  # well identified
    assert [v for v in range(35) if scheduled(v, "nominal", float("nan"))] == [10, 20, 30]
    assert not any(due(v, nominal_base(spec.description)) for v in range(70))
    assert memory_base(geometric, spec, X[:199], Y[:199]) is None  # too few points


def test_a_base_from_the_first_points_is_replaced_by_the_memorys(corner_first):
    spec, X, Y, X_test, Y_test = corner_first
    first = identify_base("geometric", spec, X[:40], Y[:40])
    late = memory_base(first, spec, X, Y)
    assert late is not None and late.kind == "geometric" and "200 points" in late.note
    first_mm = _base_mm(first, spec, X_test, Y_test)
    assert _base_mm(late, spec, X_test, Y_test) < 0.8 * first_mm  # 1.04 against 1.41 mm

    model = ErrorModel.create(
        spec, ModelConfig(hidden_layers=1, neurons=16), TrainConfig(max_epochs=30), seed=0
    )
    cfg = ContinualConfig(
        memory=300, batch=40, init=40, epochs_per_update=5, init_epochs=30, base="geometric"
    )
    learner = ContinualLearner(model, cfg)
    versions = [m.version for m in learner.learn_stream(X, Y)]
    assert versions[0] == 1 and max(versions) > FIRST_REIDENTIFY
    assert learner.base.kind == "geometric" and "200 points" in learner.base.note
    assert learner.model.base.note == learner.base.note  # published on the new base
    assert _base_mm(learner.base, spec, X_test, Y_test) < 0.8 * first_mm
