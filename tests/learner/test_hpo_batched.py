"""Folds trained as one batched model: isolation of the folds, budget, timeout, modes."""

from __future__ import annotations

import time

import numpy as np
import optuna
import pytest
import torch
from optuna.trial import TrialState

from kinematics.dataset import write_dataset
from learner.config import ModelConfig, TrainConfig
from learner.hpo import HpoConfig, cv_folds, dataset_arrays, search
from learner.hpo_batched import train_folds
from learner.hpo_config import trial_epochs
from learner.hpo_objective import cv_objective
from learner.hpo_space import SearchSpace
from learner.hpo_study import make_study, open_storage, run_trials
from learner.model import ErrorModel
from stream.cli import main
from tests.learner.test_hpo import TINY, toy_dataset

optuna.logging.set_verbosity(optuna.logging.WARNING)


@pytest.fixture(scope="module")
def arrays():
    return dataset_arrays(toy_dataset(60))


def _fold_heads(report, X_scaled, k: int, per_fold: int) -> np.ndarray:
    report.net.eval()
    with torch.inference_mode():
        gamma = report.net(X_scaled)[0]
    return gamma[:, k * per_fold : (k + 1) * per_fold].numpy()


def test_a_fold_never_learns_from_its_validation_rows(arrays):
    spec, X, Y = arrays
    folds = cv_folds(len(X), 3, seed=0)
    model_cfg = ModelConfig(hidden_layers=2, neurons=8, dropout=0.1)
    train_cfg = TrainConfig(batch_size=8, lr=3e-3, max_epochs=5)
    runs = []
    for shift in (0.0, 0.05):  # 5 cm more error on fold 0's validation rows only
        Y2 = Y.copy()
        Y2[folds[0], :3] += shift
        torch.manual_seed(0)  # the dropout masks
        runs.append(train_folds(spec, X, Y2, folds, model_cfg, train_cfg, seed=0))

    Xs = ErrorModel.create(spec, model_cfg, train_cfg, seed=0).scale_x(X)
    per_fold = 6 * model_cfg.members
    # fold 0 never saw those rows: the same network; folds 1 and 2 trained on them
    np.testing.assert_allclose(
        _fold_heads(runs[0], Xs, 0, per_fold), _fold_heads(runs[1], Xs, 0, per_fold), atol=1e-6
    )
    for k in (1, 2):
        assert not np.allclose(
            _fold_heads(runs[0], Xs, k, per_fold), _fold_heads(runs[1], Xs, k, per_fold)
        )
    assert runs[0].min_val_mse[0] != runs[1].min_val_mse[0]  # it is scored on them
    assert all(np.isfinite(runs[0].min_val_mse)) and runs[0].epochs == 5


def test_batched_and_sequential_folds_score_alike(arrays, tmp_path):
    spec, X, Y = arrays
    cfg = HpoConfig(trials=2, folds=2, max_epochs=80, min_epochs=1, top_k=2, prune=False)
    space = SearchSpace(
        hidden_layers=(1, 1), neurons=(16, 16), batch_size=(16, 16), lr=(1e-2, 1e-2)
    )
    scores = {}
    for batched in (True, False):
        c = HpoConfig(**{**cfg.__dict__, "batched_folds": batched})
        res = search(spec, X, Y, c, tmp_path / f"{batched}.journal", space=space)
        study = optuna.load_study(
            study_name=c.study, storage=open_storage(tmp_path / f"{batched}.journal")
        )
        last = max(study.trials[0].intermediate_values)
        assert last == (80 if batched else 160)  # an epoch of all folds vs fold-major steps
        scores[batched] = res.best.value
    # same rules, other random draws: both learn something of 30 points (the labels' spread
    # is 1.0) and agree (measured 0.824 batched, 0.844 sequential)
    assert scores[True] < 0.95 and scores[False] < 0.95
    assert scores[True] == pytest.approx(scores[False], rel=0.15)


def test_epoch_budget_scales_with_data_and_network():
    kw = dict(batch_size=32, max_epochs=10_000, work=5e11)
    small = trial_epochs(n_weights=1_000_000, rows=300, **kw)
    assert trial_epochs(n_weights=1_000_000, rows=3000, **kw) == pytest.approx(small / 10, abs=1)
    assert trial_epochs(n_weights=10_000_000, rows=300, **kw) == pytest.approx(small / 10, abs=1)
    assert trial_epochs(n_weights=1_000_000, rows=300, **{**kw, "work": float("inf")}) == 10_000


def test_timeout_stops_a_running_trial(arrays, tmp_path):
    spec, X, Y = arrays
    cfg = HpoConfig(trials=5, folds=2, max_epochs=100_000, min_epochs=1, trial_work=float("inf"))
    study = make_study(open_storage(tmp_path / "j.journal"), "s", seed=0, max_resource=cfg.max_step)
    start = time.monotonic()
    # 0.1 s: early stopping ends a trial of these 60 points after ~150 epochs, about 1 s on a
    # quiet machine, so a longer deadline can let the first trial complete
    objective = cv_objective(spec, X, Y, TINY, cfg, deadline=start + 0.1)
    run_trials(study, objective, cfg.trials, timeout_s=0.1)
    assert time.monotonic() - start < 10.0  # 100,000 epochs would take hours
    assert [t.state for t in study.trials] == [TrialState.PRUNED]


@pytest.mark.parametrize(
    "extra, match",
    [
        (["--trials", "0"], "hpo.trials must be an int >= 1, got 0"),
        (["--workers", "0"], "--workers must be >= 1, got 0"),
        (["--trial-work", "0"], "hpo.trial_work must be > 0"),
        (["--storage", "notadb://x"], "storage notadb://x: cannot open"),
    ],
)
def test_cli_bad_input_is_one_line_exit_2(tmp_path, capsys, extra, match):
    data = write_dataset(toy_dataset(20), tmp_path / "d.parquet")
    code = main(["hpo", "--data", str(data), "--storage", str(tmp_path / "s.journal"), *extra])
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 2 and len(err) == 1 and match in err[0], err
