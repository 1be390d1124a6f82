"""One conformance suite for every error model (River's ``check_estimator``): the protocol,
inputs left alone, ``clone``, seeded runs identical, snapshot round trip.

The project's error models are :class:`ErrorModel` in its variants (input encoding, physics
base, activation, ensemble members, dropout); ``learner.sgpr`` is a benchmark function
(fit-and-predict in one call, no snapshot), not an error model. A new model family joins by
adding a factory to ``VARIANTS``.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
import pytest
import torch

from learner.base import data_frame, make_base
from learner.config import ModelConfig, TrainConfig
from learner.features import FeatureSpec
from learner.model import ErrorModel, ErrorModelProtocol
from learner.snapshot import snapshot_from_bytes, snapshot_meta, snapshot_to_bytes
from learner.workflow import prepare

TOY = FeatureSpec(
    names=("q1", "q2", "temp_a"), low=np.array([-3.0, -2, 0]), high=np.array([3.0, 2, 60])
)
TRAIN = TrainConfig(max_epochs=4)


@dataclass(frozen=True)
class Case:
    """A fresh model of one variant (``seed``) and the data it learns from."""

    make: Callable[[int], ErrorModel]
    X: np.ndarray
    Y: np.ndarray


def _toy(model_cfg: ModelConfig) -> Case:
    rng = np.random.default_rng(0)
    X = rng.uniform(TOY.low, TOY.high, (96, 3))
    Y = 1e-3 * np.sin(X[:, :1] + np.arange(6)) + rng.normal(0, 1e-5, (96, 6))
    return Case(lambda seed: ErrorModel.create(TOY, model_cfg, TRAIN, seed, robot="toy"), X, Y)


def _kinematic_on_geometric_base(small_ds) -> Case:
    p = prepare(small_ds, seed=0)
    X, Y = p.X[p.train[:150]], p.Y[p.train[:150]]
    base = make_base("geometric", p.spec, X, Y, data_frame(small_ds))
    cfg = ModelConfig(hidden_layers=2, neurons=16)
    return Case(lambda seed: ErrorModel.create(p.spec, cfg, TRAIN, seed, p.robot, base), X, Y)


VARIANTS = {
    "minmax relu, one member": lambda ds: _toy(
        ModelConfig(hidden_layers=1, neurons=16, activation="relu", members=1, encoding="minmax")
    ),
    "minmax elu, dropout": lambda ds: _toy(
        ModelConfig(hidden_layers=2, neurons=16, activation="elu", dropout=0.2, encoding="minmax")
    ),
    "kinematic gelu on a geometric base": _kinematic_on_geometric_base,
}


@pytest.fixture(scope="module", params=list(VARIANTS))
def case(request, small_ds) -> Case:
    return VARIANTS[request.param](small_ds)


def _fit(model: ErrorModel, case: Case) -> ErrorModel:
    # Dropout masks come from torch's global generator (as ``learner.hpo.retrain`` seeds it);
    # weights and batch order come from the model's seed.
    torch.manual_seed(model.seed)
    model.fit(case.X, case.Y)
    return model


def _same(a: ErrorModel, b: ErrorModel, X: np.ndarray) -> bool:
    pa, pb = a.predict(X), b.predict(X)
    return all(np.array_equal(getattr(pa, k), getattr(pb, k)) for k in ("gamma", "nu", "alpha"))


def test_follows_the_protocol(case):
    model = case.make(0)
    assert isinstance(model, ErrorModelProtocol) and not model.is_fitted
    assert model.predict(case.X[:3]).gamma.shape == (3, 6)
    _fit(model, case)
    assert model.is_fitted and isinstance(model.clone(), ErrorModelProtocol)


def test_inputs_are_not_mutated(case):
    X, Y = case.X.copy(), case.Y.copy()
    model = _fit(case.make(0), case)
    model.predict(case.X)
    assert np.array_equal(X, case.X) and np.array_equal(Y, case.Y)


def test_clone_is_unfitted_with_the_same_hyperparameters(case):
    model = _fit(case.make(1), case)
    clone = model.clone()
    assert not clone.is_fitted and clone is not model
    for key in ("spec", "model_cfg", "train_cfg", "seed", "robot", "base"):
        assert getattr(clone, key) is getattr(model, key), key
    assert _same(_fit(clone, case), model, case.X)


def test_seeded_runs_are_identical_and_seeds_differ(case):
    a, b, c = (_fit(case.make(seed), case) for seed in (2, 2, 3))
    assert _same(a, b, case.X)
    assert not _same(a, c, case.X)


def test_snapshot_round_trip_is_bit_identical(case):
    model = _fit(case.make(4), case)
    data = snapshot_to_bytes(model)
    again = snapshot_from_bytes(data)
    assert isinstance(again, ErrorModelProtocol) and again.is_fitted
    assert _same(again, model, case.X)
    assert snapshot_meta(snapshot_to_bytes(again)) == snapshot_meta(data)
    # The reloaded model's clone learns like the original's.
    assert _same(_fit(again.clone(), case), _fit(model.clone(), case), case.X)
