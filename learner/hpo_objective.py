"""The trial objective: the k-fold CV score of residual networks, reported to the pruner.

The score of a trial is DESIGN.md's: the mean over ``folds`` folds of the minimum validation
MSE over epochs (scaled label units, see :mod:`learner.model`). All trials use the same folds.

- **Batched** (the default): all folds train at once (:mod:`learner.hpo_batched`) and every
  epoch reports, at step ``epoch``, the mean over all folds of their minimum so far. Hyperband
  compares the whole CV from the first epoch on, and the last step is the trial's score.
- **Sequential**: folds train one after the other and every epoch reports, at step
  ``fold * max_epochs + epoch``, the mean over the folds seen so far; early rungs compare the
  first fold's curves (a pruned trial never trains its other folds).

The epochs of a trial are capped by its work budget (:func:`learner.hpo_config.trial_epochs`)
and a ``deadline`` (``time.monotonic()`` s) stops a running trial as pruned.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass

import numpy as np
import optuna
import torch

from kinematics.errors import ConfigError
from learner.base import PhysicsBase
from learner.config import ModelConfig, TrainConfig
from learner.features import FeatureSpec
from learner.hpo_batched import train_folds
from learner.hpo_config import HpoConfig, trial_epochs
from learner.hpo_space import SearchSpace, TrialParams, suggest
from learner.hpo_study import Objective
from learner.model import ErrorModel


def cv_folds(n: int, k: int, seed: int) -> list[np.ndarray]:
    """Validation indices of ``k`` shuffled folds of ``n`` points (the same for every trial).

    >>> [f.size for f in cv_folds(11, 5, seed=0)]
    [3, 2, 2, 2, 2]
    """
    if n < k:
        raise ConfigError(f"hpo needs at least one point per fold: {n} points for {k} folds")
    order = np.random.default_rng(seed).permutation(n)
    return [np.sort(f) for f in np.array_split(order, k)]


def trial_configs(
    p: TrialParams, cfg: HpoConfig, max_epochs: int | None = None, val_fraction: float = 0.1
) -> tuple[ModelConfig, TrainConfig]:
    """The learner's configs for one point of the space (Adam, lr x 0.75 after 30 epochs)."""
    model_cfg = ModelConfig(
        hidden_layers=p.hidden_layers, neurons=p.neurons, activation=p.activation, dropout=p.dropout
    )
    train_cfg = TrainConfig(
        batch_size=p.batch_size,
        lr=p.lr,
        weight_decay=p.weight_decay,
        max_epochs=max_epochs or cfg.max_epochs,
        val_fraction=val_fraction,
        seed=cfg.seed,
    )
    return model_cfg, train_cfg


def cv_objective(
    spec: FeatureSpec,
    X: np.ndarray,
    Y: np.ndarray,
    space: SearchSpace,
    cfg: HpoConfig,
    base: PhysicsBase | None = None,
    deadline: float | None = None,
) -> Objective:
    """The trial objective (see the module docstring); user attributes ``n_weights`` (one
    model's), ``epochs`` (the trial's budget) and ``best_epochs`` (per fold)."""
    folds = cv_folds(len(X), cfg.folds, cfg.seed)
    rows = len(X) - max(f.size for f in folds)

    def objective(trial: optuna.Trial) -> float:
        params = suggest(trial, space)
        model_cfg, train_cfg = trial_configs(params, cfg)
        n_weights = ErrorModel.create(spec, model_cfg, train_cfg, seed=cfg.seed).n_weights
        epochs = trial_epochs(
            n_weights=n_weights * cfg.folds,
            rows=rows,
            batch_size=params.batch_size,
            max_epochs=cfg.max_epochs,
            work=cfg.trial_work,
        )
        trial.set_user_attr("n_weights", n_weights)
        trial.set_user_attr("epochs", epochs)
        model_cfg, train_cfg = trial_configs(params, cfg, max_epochs=epochs)
        cv = _CV(spec, X, Y, folds, model_cfg, train_cfg, cfg, base, deadline)
        mins, best_epochs = (_batched if cfg.batched_folds else _sequential)(trial, cv)
        trial.set_user_attr("best_epochs", best_epochs)
        return float(np.mean(mins))

    return objective


def _check(trial: optuna.Trial, deadline: float | None, where: str) -> None:
    if deadline is not None and time.monotonic() > deadline:
        raise optuna.TrialPruned(f"timeout at {where}")
    if trial.should_prune():
        raise optuna.TrialPruned(f"pruned at {where}")


@dataclass(frozen=True)
class _CV:
    """What one trial's folds train on: the data, the folds, the trial's configs, the base
    and the deadline (``time.monotonic()`` s)."""

    spec: FeatureSpec
    X: np.ndarray
    Y: np.ndarray
    folds: list[np.ndarray]
    model_cfg: ModelConfig
    train_cfg: TrainConfig
    cfg: HpoConfig
    base: PhysicsBase | None
    deadline: float | None


def _batched(trial: optuna.Trial, cv: _CV) -> tuple[list[float], list[int]]:
    """All folds in one batched model; reports the mean over folds every epoch. Per fold the
    minimum validation MSE (scaled label units) and its epoch."""
    torch.manual_seed(cv.cfg.seed)  # dropout masks come from torch's global generator

    def on_epoch(epoch: int, running: np.ndarray) -> None:
        trial.report(float(np.mean(running)), step=epoch)
        _check(trial, cv.deadline, f"epoch {epoch}")

    data = (cv.spec, cv.X, cv.Y, cv.folds, cv.model_cfg, cv.train_cfg)
    try:
        report = train_folds(
            *data, seed=cv.cfg.seed, base=cv.base, on_epoch=on_epoch, deadline=cv.deadline
        )
    except TimeoutError as exc:
        raise optuna.TrialPruned(f"timeout: {exc}") from None
    return list(report.min_val_mse), list(report.best_epochs)


def _sequential(trial: optuna.Trial, cv: _CV) -> tuple[list[float], list[int]]:
    """One fold after the other (fold-major steps); reports the running mean every epoch."""
    X, Y, seed = cv.X, cv.Y, cv.cfg.seed
    mins: list[float] = []
    best_epochs: list[int] = []
    for k, val in enumerate(cv.folds):
        train = np.setdiff1d(np.arange(len(X)), val)
        model = ErrorModel.create(cv.spec, cv.model_cfg, cv.train_cfg, seed=seed + k, base=cv.base)
        running = [math.inf]
        torch.manual_seed(seed + k)  # dropout masks come from torch's global generator

        def on_epoch(epoch: int, val_mse: float, k: int = k, running: list = running) -> None:
            if math.isfinite(val_mse):
                running[0] = min(running[0], val_mse)
            trial.report((sum(mins) + running[0]) / (k + 1), step=k * cv.cfg.max_epochs + epoch)
            _check(trial, cv.deadline, f"fold {k}, epoch {epoch}")

        report = model.fit(X[train], Y[train], X[val], Y[val], on_epoch=on_epoch)
        mins.append(running[0])
        best_epochs.append(report.best_epoch)
    return mins, best_epochs
