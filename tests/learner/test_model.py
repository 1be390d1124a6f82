import numpy as np
import pytest

from kinematics.description import load_description
from kinematics.errors import DatasetError
from kinematics.model import RobotModel
from learner.config import ModelConfig, TrainConfig
from learner.evidential import served_mean
from learner.features import FeatureSpec, dataset_feature_spec, dataset_features, dataset_labels
from learner.model import ErrorModel

FANUC = load_description("fanuc_m900ib700")
TINY = ModelConfig(hidden_layers=2, neurons=32)
MINMAX = ModelConfig(hidden_layers=2, neurons=32, encoding="minmax")


@pytest.fixture(scope="module")
def data(small_ds):
    spec = dataset_feature_spec(small_ds, FANUC)
    return spec, dataset_features(small_ds, spec), dataset_labels(small_ds, RobotModel(FANUC))


def _model(spec, seed=0, cfg=TINY, **train):
    train_cfg = TrainConfig(**({"batch_size": 64, "lr": 3e-3, "max_epochs": 40} | train))
    return ErrorModel.create(spec, cfg, train_cfg, seed=seed, robot=FANUC.name)


def _mean_mm(model, X, Y):
    return np.linalg.norm(model.predict(X).gamma[:, :3] - Y[:, :3], axis=1).mean() * 1e3


def test_fit_learns_and_is_reproducible():
    rng = np.random.default_rng(0)
    X = rng.uniform(-1, 1, (400, 2))
    Y = 1e-3 * np.sin(2 * X[:, :1] + np.arange(6)) * np.cos(X[:, 1:2])
    spec = FeatureSpec(names=("q1", "q2"), low=np.array([-1.0, -1.0]), high=np.array([1.0, 1.0]))
    a, b = _model(spec, cfg=MINMAX), _model(spec, cfg=MINMAX)
    ra, rb = a.fit(X[:300], Y[:300]), b.fit(X[:300], Y[:300])
    constant = np.linalg.norm(Y[300:, :3] - Y[:300, :3].mean(axis=0), axis=1).mean() * 1e3
    assert _mean_mm(a, X[300:], Y[300:]) < 0.2 * constant
    np.testing.assert_array_equal(a.predict(X[300:]).gamma, b.predict(X[300:]).gamma)
    assert ra.val_mse_history == rb.val_mse_history and ra.skipped_steps == 0


def test_best_weights_are_kept_and_on_epoch_sees_every_epoch(data):
    spec, X, Y = data
    m = _model(spec, max_epochs=25)
    seen = []
    report = m.fit(X[:200], Y[:200], X[200:260], Y[200:260], on_epoch=lambda e, v: seen.append(v))
    assert len(seen) == report.epochs == 25
    assert report.best_val_mse == min(seen)
    pred = served_mean(*m.predict_scaled(m.scale_x(X[200:260])))
    val_mse = float(((pred - m.scale_y(Y[200:260])) ** 2).mean())
    assert val_mse == pytest.approx(report.best_val_mse, rel=1e-5)


def test_exception_from_on_epoch_propagates(data):
    spec, X, Y = data

    class PrunedError(Exception):
        pass

    def prune(epoch, val_mse):
        if epoch == 3:
            raise PrunedError

    with pytest.raises(PrunedError):
        _model(spec).fit(X[:100], Y[:100], on_epoch=prune)


def _mirrored(Y_train, Y_val):
    """Validation labels mirrored about the training labels' mean: the better a network fits the
    training points, the worse it scores on them, so a run with early stopping stops long before
    its budget on any CPU's rounding (as they came, one VM's run still improved at epoch 56)."""
    return 2 * Y_train.mean(axis=0) - Y_val


def test_lr_is_cut_after_plateau_and_early_stop(data):
    spec, X, Y = data
    m = _model(spec, max_epochs=200, patience_lr=1, early_stop_patience=5, lr=0.3)
    raw = []  # the network's own mean's val MSE, watched as the loop scores it
    Y_val = _mirrored(Y[:100], Y[100:130])

    def watch(epoch, served):
        gamma = m.predict_scaled(m.scale_x(X[100:130]))[0]
        raw.append(float(((gamma - m.scale_y(Y_val)) ** 2).mean()))

    report = m.fit(X[:100], Y[:100], X[100:130], Y_val, on_epoch=watch)
    assert report.final_lr < 0.3
    # the best served score's weights are kept; the run stops 5 epochs after the later of the
    # two scores' last improvement
    best_served = int(np.argmin(report.val_mse_history)) + 1
    assert report.best_epoch == best_served
    assert report.epochs < 200
    assert report.epochs - max(best_served, int(np.argmin(raw)) + 1) == 5


def test_an_annealed_fit_runs_its_budget_with_the_rate_falling_to_zero(data):
    """A continual update's fixed budget: the rate follows a half cosine to 0 over every epoch,
    never cut on a plateau nor stopped early; the best epoch's weights are still kept."""
    spec, X, Y = data
    fit = {"X_val": X[100:130], "Y_val": _mirrored(Y[:100], Y[100:130]), "lr": 0.3}
    train = {"max_epochs": 100, "patience_lr": 1, "early_stop_patience": 5}
    plateau = _model(spec, **train).fit(X[:100], Y[:100], **fit)
    annealed = _model(spec, **train).fit(X[:100], Y[:100], anneal=True, **fit)
    assert plateau.epochs < 100 and 0 < plateau.final_lr < 0.3
    assert annealed.epochs == 100 and annealed.final_lr == pytest.approx(0.0, abs=1e-12)
    assert annealed.best_epoch == int(np.argmin(annealed.val_mse_history)) + 1


def test_non_finite_loss_never_reaches_weights(data):
    spec, X, Y = data
    m = _model(spec, max_epochs=2)
    m.fit(X[:64], Y[:64])
    before = [p.detach().clone() for p in m.net.parameters()]
    m.label_std = np.full(6, 1e-40)  # scaled labels overflow float32: every loss is inf
    report = m.fit(X[:64], Y[:64], val_fraction=0.0)
    assert report.skipped_steps == 2 and m.skipped_steps == 2
    for p, q in zip(before, m.net.parameters(), strict=True):
        assert np.array_equal(p.numpy(), q.detach().numpy())


def test_label_scaler_is_fixed_by_the_first_fit(data):
    spec, X, Y = data
    m = _model(spec, max_epochs=1)
    m.fit(X[:50], Y[:50])
    mean, std = m.label_mean.copy(), m.label_std.copy()
    m.fit(X[50:100] * 1.0, Y[50:100] * 3.0)
    np.testing.assert_array_equal(m.label_mean, mean)
    np.testing.assert_array_equal(m.label_std, std)


def test_calibration_lowers_held_out_nll(data):
    spec, X, Y = data
    m = _model(spec, max_epochs=30)
    m.fit(X[:250], Y[:250], val_fraction=0.0)
    m.interval_scale = np.ones(6)
    before = m.predict(X[250:]).nll(Y[250:]).sum(axis=0)
    scale = m.calibrate(X[250:], Y[250:])
    after = m.predict(X[250:]).nll(Y[250:]).sum(axis=0)
    assert np.all(scale > 0) and np.all(after <= before + 1e-9)


def test_validation_rows_are_the_ones_fit_held_out(data):
    """What ``--base best`` compares models on: the points each fit held out, not trained on."""
    spec, X, Y = data
    m = _model(spec, max_epochs=3)
    m.fit(X[:200], Y[:200])
    held = m.validation_rows(200)
    assert len(held) == 20 and len(set(held.tolist())) == 20
    np.testing.assert_array_equal(held, _model(spec, max_epochs=3).validation_rows(200))
    scale = m.interval_scale.copy()  # fit calibrated on its validation points
    np.testing.assert_allclose(m.calibrate(X[:200][held], Y[:200][held]), scale)
    assert not np.allclose(m.calibrate(X[:20], Y[:20]), scale)
    assert len(m.validation_rows(9)) == 0


def test_bad_shapes_raise(data):
    spec, X, Y = data
    m = _model(spec)
    with pytest.raises(DatasetError, match="rows"):
        m.fit(X[:10], Y[:9])
    with pytest.raises(DatasetError, match=r"\(N, 6\)"):
        m.fit(X[:10], Y[:10, :3])
    with pytest.raises(DatasetError, match="shape"):
        m.predict(X[:, :3])
    assert m.n_weights == m.net.n_weights > 0
