from dataclasses import replace

import numpy as np
import pytest

from kinematics.errors import ConfigError, DatasetError, SnapshotError
from learner.config import ContinualConfig, ModelConfig, TrainConfig
from learner.continual import ContinualLearner
from learner.continual_state import state_from_bytes, state_to_bytes
from learner.features import FeatureSpec
from learner.model import ErrorModel

SPEC = FeatureSpec(names=("q1", "q2"), low=np.array([-1.0, -1.0]), high=np.array([1.0, 1.0]))


def _target(X):
    k = np.arange(6)
    return 1e-3 * np.sin(3 * X[:, :1] + k) * np.cos(2 * X[:, 1:2] - k) + 1e-3 * X[:, :1] ** 2


def _region(rng, n, lo, hi):
    X = np.column_stack([rng.uniform(lo, hi, n), rng.uniform(-1, 1, n)])
    return X, _target(X)


def _learner(strategy, memory=100, batch=25, epochs=30, seed=0, holdout=0.0, average=0.3):
    model = ErrorModel.create(
        SPEC,
        ModelConfig(hidden_layers=2, neurons=24, encoding="minmax"),
        TrainConfig(batch_size=32, lr=3e-3, max_epochs=150),
        seed=seed,
    )
    cfg = ContinualConfig(
        memory=memory,
        batch=batch,
        init=25,
        strategy=strategy,
        epochs_per_update=epochs,
        init_epochs=150,
        update_lr=3e-3,  # this toy learns each region in few, short updates
        holdout=holdout,
        calibration_size=20,
        average=average,
        refresh_growth=0,  # a fresh network as the stream grows: tests/learner/test_refresh.py
    )
    return ContinualLearner(model, cfg)


def _stream(learner, X, Y):
    """The first model from ``init`` (25) points, then one update per batch of 25."""
    steps = list(learner.learn_stream(X, Y))
    assert [m.n_seen for m in steps] == list(range(25, len(X) + 1, 25))
    return steps


@pytest.fixture(scope="module")
def two_regions():
    rng = np.random.default_rng(0)
    X1, Y1 = _region(rng, 100, -1, 0)
    X2, Y2 = _region(rng, 100, 0, 1)
    Xt, Yt = _region(rng, 200, -1, 0)
    return np.concatenate([X1, X2]), np.concatenate([Y1, Y2]), Xt, Yt


def test_max_error_keeps_region_one_while_naive_forgets(two_regions):
    # The replay alone: averaging the weights over updates (tested below) would hide part of
    # what naive fine-tuning forgets in four updates.
    X, Y, Xt, Yt = two_regions
    errors = {}
    for strategy in ("max_error", "naive"):
        learner = _learner(strategy, average=1.0)
        _stream(learner, X[:100], Y[:100])
        before = np.abs(learner.model.predict(Xt).gamma - Yt).mean()
        for i in range(100, 200, 25):
            learner.update(X[i : i + 25], Y[i : i + 25])
        after = np.abs(learner.model.predict(Xt).gamma - Yt).mean()
        errors[strategy] = (before, after)
    assert errors["max_error"][1] < 1.5 * errors["max_error"][0]
    assert errors["naive"][1] > 3 * errors["naive"][0]
    assert errors["naive"][1] > 3 * errors["max_error"][1]


def test_memory_holds_the_largest_errors_and_its_size(two_regions):
    X, Y, _, _ = two_regions
    learner = _learner("max_error", memory=40, epochs=2)
    learner.initialize(X[:25], Y[:25])
    mem = learner.memory
    pool_x = np.concatenate([mem.x, X[25:50]])
    pool_y = np.concatenate([mem.y, Y[25:50]])
    err = np.linalg.norm(
        (learner.model.predict(pool_x).gamma - pool_y) / learner.model.label_std, axis=1
    )
    metrics = learner.update(X[25:50], Y[25:50])
    assert metrics.memory_size == len(learner.memory) == 40
    kept = {tuple(row) for row in learner.memory.x}
    want = {tuple(row) for row in pool_x[np.argsort(-err)[:40]]}
    assert kept == want
    assert metrics.n_seen == 50 and metrics.version == 2


@pytest.mark.parametrize(
    "strategy, size", [("naive", 25), ("full", 75), ("reservoir", 40), ("max_error", 40)]
)
def test_every_strategy_runs_through_update(two_regions, strategy, size):
    X, Y, _, _ = two_regions
    learner = _learner(strategy, memory=40, epochs=1)
    metrics = _stream(learner, X[:75], Y[:75])
    assert metrics[-1].memory_size == size
    assert np.isfinite(metrics[-1].batch_mean_mm) and np.isfinite(metrics[-1].train_mean_mm)


def test_updates_before_init_collect_points(two_regions):
    X, Y, _, _ = two_regions
    learner = _learner("max_error", epochs=1)
    first = learner.update(X[:10], Y[:10])
    assert first.version == 0 and first.epochs == 0 and not learner.model.is_fitted
    second = learner.update(X[10:30], Y[10:30])
    assert second.version == 1 and learner.model.is_fitted and second.n_seen == 30


def test_state_roundtrip_continues_identically(two_regions):
    X, Y, _, _ = two_regions
    a = _learner("reservoir", memory=30, epochs=2)
    _stream(a, X[:75], Y[:75])
    state = state_from_bytes(state_to_bytes(a.state_dict()))
    b = _learner("reservoir", memory=30, epochs=2, seed=5)
    b.load_state(state)
    assert b.n_seen == a.n_seen and b.version == a.version
    np.testing.assert_array_equal(b.memory.x, a.memory.x)
    np.testing.assert_array_equal(b.model.predict(X[:5]).gamma, a.model.predict(X[:5]).gamma)
    ma, mb = a.update(X[75:100], Y[75:100]), b.update(X[75:100], Y[75:100])
    np.testing.assert_array_equal(a.memory.x, b.memory.x)
    assert ma.memory_size == mb.memory_size
    for model in ("model", "trained"):
        np.testing.assert_array_equal(
            getattr(b, model).predict(X[:5]).gamma, getattr(a, model).predict(X[:5]).gamma
        )


def test_a_state_without_trained_weights_trains_the_published_ones(two_regions):
    X, Y, _, _ = two_regions
    a = _learner("max_error", memory=30, epochs=2)
    _stream(a, X[:50], Y[:50])
    state = a.state_dict()
    del state["trained"]
    b = _learner("max_error", memory=30, epochs=2)
    b.load_state(state)
    np.testing.assert_array_equal(b.trained.predict(X[:5]).gamma, a.model.predict(X[:5]).gamma)


def _weights(model):
    return [t.clone() for t in model.net.state_dict().values()]


@pytest.mark.parametrize("average", [0.3, 1.0])
def test_the_published_model_averages_the_trained_weights(two_regions, average):
    X, Y, _, _ = two_regions
    learner = _learner("max_error", epochs=5, holdout=0.2, average=average)
    _stream(learner, X[:75], Y[:75])
    before = _weights(learner.model)
    learner.update(X[75:100], Y[75:100])
    trained, after = _weights(learner.trained), _weights(learner.model)
    assert any(not np.allclose(b, t) for b, t in zip(before, trained, strict=True))
    for b, t, a in zip(before, trained, after, strict=True):
        np.testing.assert_allclose(a, b + average * (t - b), rtol=1e-6, atol=1e-7)
    state = learner.state_dict()
    held_x, held_y = state["holdout_x"], state["holdout_y"]
    scale = learner.model.interval_scale.copy()
    aci = np.exp(learner.aci_log_scale)  # the adaptive conformal factor on the calibrated scale
    np.testing.assert_allclose(learner.model.calibrate(held_x, held_y) * aci, scale)
    if average == 1.0:
        np.testing.assert_array_equal(
            learner.model.predict(X).gamma, learner.trained.predict(X).gamma
        )


def test_held_out_points_calibrate_and_are_never_trained(two_regions):
    X, Y, _, _ = two_regions
    learner = _learner("full", memory=200, epochs=2, holdout=0.2)
    _stream(learner, X[:125], Y[:125])
    state = learner.state_dict()
    held, memory = state["holdout_x"], learner.memory.x
    assert len(held) == 20  # 5 per batch of 25, the latest 20 of 4 updates
    assert not {tuple(r) for r in held} & {tuple(r) for r in memory}
    assert len(memory) == 25 + 4 * 20 and learner.n_seen == 125
    scale = learner.model.interval_scale.copy()
    aci = np.exp(learner.aci_log_scale)
    np.testing.assert_allclose(
        learner.model.calibrate(held, Y[np.isin(X[:, 0], held[:, 0])]) * aci, scale
    )
    back = _learner("full", memory=200, epochs=2, holdout=0.2)
    back.load_state(state_from_bytes(state_to_bytes(state)))
    np.testing.assert_array_equal(back.state_dict()["holdout_x"], held)


def test_each_update_reports_how_its_batch_was_covered_before_it_was_learned(two_regions):
    from learner.continual_records import prequential
    from learner.metrics import accuracy_report
    from learner.snapshot import copy_model

    X, Y, _, _ = two_regions
    learner = _learner("max_error", memory=200, epochs=10, holdout=0.2)
    learner.initialize(X[:25], Y[:25])
    steps, expected = [], []
    for i in range(25, 200, 25):
        published = copy_model(learner.model)  # what a line asking now would be answered by
        expected.append(accuracy_report(published, X[i : i + 25], Y[i : i + 25]).coverage_90)
        steps.append(learner.update(X[i : i + 25], Y[i : i + 25]))
    np.testing.assert_allclose([m.batch_coverage_90 for m in steps], expected)
    first, second = np.mean(expected[:3]), expected[3]  # region two starts at point 100
    assert second < first  # a region never learned is covered worse, and the record says so
    pooled = prequential(steps)
    assert pooled["n_points"] == 7 * 20  # the points each update learned, its held-out 5 apart
    assert pooled["coverage_90"] == pytest.approx(np.mean(expected))  # equal batches
    assert np.isnan(learner.update(X[:0], Y[:0]).batch_coverage_90)  # nothing scored


def test_bad_batches_and_states_raise():
    learner = _learner("max_error")
    with pytest.raises(DatasetError, match="shape"):
        learner.update(np.zeros((3, 5)), np.zeros((3, 6)))
    with pytest.raises(DatasetError, match="non-finite"):
        learner.update(np.full((3, 2), np.nan), np.zeros((3, 6)))
    with pytest.raises(SnapshotError):
        state_from_bytes(b"garbage")
    with pytest.raises(SnapshotError, match="incomplete"):
        learner.load_state({"n_seen": 1})


def _holdout_mse(learner):
    """The validation score of ``ErrorModel.fit``: MSE of the scaled means on the held-out set."""
    state = learner.state_dict()
    model = learner.trained
    gamma = model.predict_scaled(model.scale_x(state["holdout_x"]))[0]
    return float(((gamma - model.scale_y(state["holdout_y"])) ** 2).mean())


def test_an_update_keeps_the_weights_best_on_the_held_out_set(two_regions):
    # From the same state, a longer update can only end at least as good on the held-out set:
    # its candidate epochs include the shorter one's. Noisy labels and a high rate make the
    # last epochs overfit, so keeping the last weights fails this test.
    X, Y, _, _ = two_regions
    Y = Y + 1e-3 * np.random.default_rng(3).standard_normal(Y.shape)
    start = _learner("max_error", epochs=5, holdout=0.2)
    _stream(start, X[:75], Y[:75])
    scores = []
    for epochs in (5, 40):
        learner = _learner("max_error", holdout=0.2)
        learner.cfg = replace(learner.cfg, epochs_per_update=epochs, update_lr=0.05)
        learner.load_state(start.state_dict())
        learner.update(X[75:100], Y[75:100])
        scores.append(_holdout_mse(learner))
    assert scores[1] <= scores[0] + 1e-9


def test_a_memory_above_update_points_trains_fewer_epochs(two_regions):
    # An update costs about the same whatever the memory: 20 epochs over up to 40 points.
    X, Y, _, _ = two_regions
    learner = _learner("max_error", memory=100, epochs=20)
    learner.cfg = replace(learner.cfg, update_points=40)
    steps = _stream(learner, X[:100], Y[:100])[1:]
    assert [m.memory_size for m in steps] == [50, 75, 100]
    assert [m.epochs for m in steps] == [16, 11, 8]
    learner = _learner("max_error", memory=100, epochs=20)
    assert [m.epochs for m in _stream(learner, X[:100], Y[:100])[1:]] == [20, 20, 20]


def test_update_points_must_be_a_positive_count():
    with pytest.raises(ConfigError, match="update_points"):
        ContinualConfig(update_points=0)
