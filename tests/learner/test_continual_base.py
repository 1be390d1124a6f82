"""A continual learner identifies its physics base again: from every trained point each time
they double, and a base left on the nominal from points spread over its replay memory."""

import numpy as np
import pytest

from kinematics.model import RobotModel
from learner.base import identify_base, nominal_base
from learner.config import ContinualConfig, ModelConfig, TrainConfig
from learner.continual import ContinualLearner
from learner.continual_base import doubled, due, memory_base, refined_base, scheduled, status
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
    assert not any(due(v, geometric) for v in range(70))  # refined as its points double
    assert [v for v in range(35) if scheduled(v, "nominal")] == [10, 20, 30]
    assert not any(due(v, nominal_base(spec.description)) for v in range(70))
    assert memory_base(geometric, spec, X[:199], Y[:199]) is None  # too few points
    assert [n for n in range(0, 700) if doubled(n, n + 1, 40)] == [39, 79, 159, 319, 639]
    assert refined_base(geometric, spec, X[:8], Y[:8]) is None  # too few to identify it


def test_a_base_from_the_first_points_is_replaced_by_the_memorys(corner_first):
    spec, X, Y, X_test, Y_test = corner_first
    first = identify_base("geometric", spec, X[:40], Y[:40])
    late = memory_base(first, spec, X, Y)
    assert late is not None and late.kind == "geometric" and "200 points" in late.note
    first_mm = _base_mm(first, spec, X_test, Y_test)
    assert _base_mm(late, spec, X_test, Y_test) < 0.8 * first_mm  # 1.04 against 1.41 mm
    refined = refined_base(first, spec, X, Y)
    assert refined.kind == "geometric" and "400 points" in refined.note
    assert _base_mm(refined, spec, X_test, Y_test) < 0.8 * first_mm


@pytest.mark.parametrize("memory", [300, 150])
def test_a_stream_refines_its_base_while_the_memory_holds_every_point(corner_first, memory):
    """40 points, then 36 trained per batch: refined on 112 and 184 points (past 80 and 160);
    with memory 150 on 112 only: at 184 the memory drops points, and the base stays."""
    spec, X, Y, X_test, Y_test = corner_first
    model = ErrorModel.create(
        spec, ModelConfig(hidden_layers=1, neurons=16), TrainConfig(max_epochs=30), seed=0
    )
    cfg = ContinualConfig(
        memory=memory, batch=40, init=40, epochs_per_update=5, init_epochs=30, base="geometric"
    )
    learner = ContinualLearner(model, cfg)
    notes = {m.version: learner.base.note for m in learner.learn_stream(X, Y)}
    assert notes[1].startswith("identified from 40 points")
    last = 184 if memory == 300 else 112
    assert learner.base.kind == "geometric" and f"from {last} points" in learner.base.note
    assert learner.model.base.note == learner.base.note  # published on it
    first = identify_base("geometric", spec, X[:40], Y[:40])
    if memory == 300:
        assert _base_mm(learner.base, spec, X_test, Y_test) < 0.8 * _base_mm(
            first, spec, X_test, Y_test
        )
