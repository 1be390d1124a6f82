"""Hyperparameter search for the evidential ensemble: TPE + Hyperband over k-fold CV.

The score of a trial is DESIGN.md's: the mean over ``folds`` cross-validation folds of the
minimum validation MSE over epochs (scaled label units, see :mod:`learner.model`). Folds run
one after the other (fold-major) and every epoch reports, at step ``fold * max_epochs +
epoch``, the running score: the mean over the folds seen so far of their minimum validation
MSE so far. All trials use the same folds, so at a given step every trial has seen the same
data and the values are comparable: Hyperband's early rungs compare the first fold's learning
curves (most of the saving: a pruned trial never trains its other folds), its late rungs
compare means over several folds, and the last step is exactly the trial's score.

Among the ``top_k`` best trials the one with the fewest weights is retrained on all data for
the mean best epoch of its folds and written as a snapshot (:mod:`learner.snapshot`).
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable
from dataclasses import asdict, dataclass, field, fields
from pathlib import Path

import numpy as np
import optuna
import torch
from optuna.trial import FrozenTrial, TrialState

from kinematics.dataset import Dataset
from kinematics.errors import ConfigError
from kinematics.identity import description_for
from kinematics.model import RobotModel
from learner.base import DEFAULT_BASE, PhysicsBase, data_frame, make_base
from learner.config import ModelConfig, TrainConfig
from learner.features import FeatureSpec, dataset_feature_spec, dataset_features, dataset_labels
from learner.hpo_space import SearchSpace, TrialParams, suggest
from learner.hpo_study import (
    Objective,
    Progress,
    lock_path,
    make_study,
    open_storage,
    run_trials,
    select_trial,
    top_trials,
)
from learner.model import ErrorModel
from learner.snapshot import save_snapshot


@dataclass(frozen=True, kw_only=True)
class HpoConfig:
    """The search: trial budget, CV folds, epochs per fold, Hyperband rungs, selection."""

    trials: int = 50
    timeout_s: float | None = None
    folds: int = 5
    max_epochs: int = 200
    min_epochs: int = 10
    reduction_factor: int = 3
    startup_trials: int = 10
    prune: bool = True
    top_k: int = 10
    seed: int = 0
    study: str = "robocal-hpo"

    def __post_init__(self) -> None:
        for key in ("trials", "max_epochs", "min_epochs", "top_k", "startup_trials"):
            value = getattr(self, key)
            if not isinstance(value, int) or value < 1:
                raise ConfigError(f"hpo.{key} must be an int >= 1, got {value!r}")
        if not isinstance(self.folds, int) or self.folds < 2:
            raise ConfigError(f"hpo.folds must be an int >= 2, got {self.folds!r}")
        if not isinstance(self.reduction_factor, int) or self.reduction_factor < 2:
            raise ConfigError(
                f"hpo.reduction_factor must be an int >= 2, got {self.reduction_factor!r}"
            )
        if self.min_epochs > self.max_step:
            raise ConfigError(
                f"hpo.min_epochs must be <= folds * max_epochs = {self.max_step}, "
                f"got {self.min_epochs}"
            )
        if self.timeout_s is not None and not self.timeout_s > 0:
            raise ConfigError(f"hpo.timeout_s must be > 0, got {self.timeout_s}")
        if not self.study:
            raise ConfigError("hpo.study must be a non-empty name, got ''")

    @property
    def max_step(self) -> int:
        """The last step a trial reports: every epoch of every fold."""
        return self.folds * self.max_epochs


@dataclass(frozen=True, kw_only=True)
class TrialRow:
    """One trial of the table: number, CV score (scaled MSE), weights and parameters."""

    number: int
    value: float
    n_weights: int
    params: TrialParams

    @classmethod
    def of(cls, t: FrozenTrial) -> TrialRow:
        return cls(
            number=t.number,
            value=float(t.value),
            n_weights=int(t.user_attrs.get("n_weights", -1)),
            params=TrialParams.from_dict(t.params),
        )


@dataclass(frozen=True, kw_only=True)
class HpoResult:
    """What a search did: trial counts over the whole study, the best and selected trials, the
    table of the best ones, the retrained snapshot and this worker's wall time (s)."""

    study: str
    storage: str
    requested: int
    complete: int
    pruned: int
    failed: int
    ran_here: int
    wall_s: float
    best: TrialRow
    selected: TrialRow
    top: tuple[TrialRow, ...]
    retrain_epochs: int
    snapshot: str
    model: ErrorModel | None = field(default=None, repr=False, compare=False)

    def to_dict(self) -> dict:
        """JSON-ready: every field but the model; rows as dicts."""
        out = {f.name: getattr(self, f.name) for f in fields(self) if f.name != "model"}
        out.update(
            best=asdict(self.best),
            selected=asdict(self.selected),
            top=[asdict(r) for r in self.top],
        )
        return out

    def table(self) -> str:
        """The best trials as text, the selected one marked ``*``."""
        head = (
            f"{'':1} {'trial':>5} {'cv mse':>10} {'weights':>9} {'layers':>6} {'neurons':>7} "
            f"{'act':>4} {'batch':>5} {'lr':>8} {'decay':>8} {'dropout':>7}"
        )
        lines = [head]
        for r in self.top:
            p = r.params
            mark = "*" if r.number == self.selected.number else ""
            lines.append(
                f"{mark:1} {r.number:>5} {r.value:>10.4g} {r.n_weights:>9} {p.hidden_layers:>6} "
                f"{p.neurons:>7} {p.activation:>4} {p.batch_size:>5} {p.lr:>8.2e} "
                f"{p.weight_decay:>8.2e} {p.dropout:>7.3f}"
            )
        return "\n".join(lines)


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
) -> Objective:
    """The trial objective: k-fold CV score of residual networks on ``base``, reported every
    epoch (see the module docstring)."""
    folds = cv_folds(len(X), cfg.folds, cfg.seed)

    def objective(trial: optuna.Trial) -> float:
        model_cfg, train_cfg = trial_configs(suggest(trial, space), cfg)
        mins: list[float] = []
        best_epochs: list[int] = []
        for k, val in enumerate(folds):
            train = np.setdiff1d(np.arange(len(X)), val)
            model = ErrorModel.create(spec, model_cfg, train_cfg, seed=cfg.seed + k, base=base)
            if k == 0:
                trial.set_user_attr("n_weights", model.n_weights)
            running = [math.inf]
            torch.manual_seed(cfg.seed + k)  # dropout masks come from torch's global generator

            def on_epoch(epoch: int, val_mse: float, k: int = k, running: list = running) -> None:
                if math.isfinite(val_mse):
                    running[0] = min(running[0], val_mse)
                trial.report((sum(mins) + running[0]) / (k + 1), step=k * cfg.max_epochs + epoch)
                if trial.should_prune():
                    raise optuna.TrialPruned(f"pruned at fold {k}, epoch {epoch}")

            report = model.fit(X[train], Y[train], X[val], Y[val], on_epoch=on_epoch)
            mins.append(running[0])
            best_epochs.append(report.best_epoch)
        trial.set_user_attr("best_epochs", best_epochs)
        return float(np.mean(mins))

    return objective


def search(
    spec: FeatureSpec,
    X: np.ndarray,
    Y: np.ndarray,
    cfg: HpoConfig,
    storage: str | Path,
    *,
    space: SearchSpace | None = None,
    out: str | Path | None = None,
    robot: str = "",
    on_trial: Callable[[Progress], None] | None = None,
    base: PhysicsBase | None = None,
) -> HpoResult:
    """Run (or resume, or join) the study on ``storage`` up to ``cfg.trials`` trials, select
    among the best the smallest model, retrain it on all of ``X, Y`` and save it to ``out``.
    Every network learns the residual of ``base`` (None: the nominal)."""
    start = time.perf_counter()
    study = make_study(
        open_storage(storage),
        cfg.study,
        seed=cfg.seed,
        max_resource=cfg.max_step,
        min_resource=cfg.min_epochs,
        reduction_factor=cfg.reduction_factor,
        prune=cfg.prune,
        n_startup_trials=cfg.startup_trials,
    )
    objective = cv_objective(spec, X, Y, space or SearchSpace(), cfg, base)
    mine = run_trials(
        study,
        objective,
        cfg.trials,
        timeout_s=cfg.timeout_s,
        lock=lock_path(storage),
        on_trial=on_trial,
    )
    chosen = select_trial(study, cfg.top_k)
    epochs = max(1, round(float(np.mean(chosen.user_attrs.get("best_epochs", [cfg.max_epochs])))))
    model = retrain(spec, X, Y, TrialParams.from_dict(chosen.params), cfg, epochs, robot, base)
    model.metrics["cv_val_mse"] = float(chosen.value)
    if out is not None:
        hpo_meta = {"study": cfg.study, "trial": chosen.number, "params": chosen.params}
        save_snapshot(model, out, extra_meta={"hpo": hpo_meta})
    counts = {s: len(study.get_trials(deepcopy=False, states=(s,))) for s in TrialState}
    return HpoResult(
        study=cfg.study,
        storage=str(storage),
        requested=cfg.trials,
        complete=counts[TrialState.COMPLETE],
        pruned=counts[TrialState.PRUNED],
        failed=counts[TrialState.FAIL],
        ran_here=len(mine),
        wall_s=time.perf_counter() - start,
        best=TrialRow.of(top_trials(study, 1)[0]),
        selected=TrialRow.of(chosen),
        top=tuple(TrialRow.of(t) for t in top_trials(study, cfg.top_k)),
        retrain_epochs=epochs,
        snapshot="" if out is None else str(out),
        model=model,
    )


def retrain(
    spec: FeatureSpec,
    X: np.ndarray,
    Y: np.ndarray,
    params: TrialParams,
    cfg: HpoConfig,
    epochs: int,
    robot: str = "",
    base: PhysicsBase | None = None,
) -> ErrorModel:
    """A fresh model of ``params`` on ``base`` trained on all of ``X, Y`` for ``epochs``."""
    model_cfg, train_cfg = trial_configs(params, cfg, max_epochs=epochs, val_fraction=0.0)
    model = ErrorModel.create(spec, model_cfg, train_cfg, seed=cfg.seed, robot=robot, base=base)
    torch.manual_seed(cfg.seed)  # dropout masks come from torch's global generator
    model.fit(X, Y)
    return model


def dataset_arrays(ds: Dataset) -> tuple[FeatureSpec, np.ndarray, np.ndarray]:
    """Every feature the dataset has, its raw SI features and its pose-error labels."""
    desc = description_for(ds)
    spec = dataset_feature_spec(ds, desc)
    return spec, dataset_features(ds, spec), dataset_labels(ds, RobotModel(desc))


def run_hpo(
    ds: Dataset,
    cfg: HpoConfig,
    storage: str | Path,
    *,
    space: SearchSpace | None = None,
    out: str | Path | None = None,
    on_trial: Callable[[Progress], None] | None = None,
    base: str = DEFAULT_BASE,
) -> HpoResult:
    """:func:`search` on every feature and the labels of a dataset (what ``robocal hpo`` runs),
    on the physics ``base`` identified from all its points (a few dozen parameters, shared by
    every fold: the folds compare networks, not bases)."""
    spec, X, Y = dataset_arrays(ds)
    physics = make_base(base, spec, X, Y, data_frame(ds))
    return search(
        spec,
        X,
        Y,
        cfg,
        storage,
        space=space,
        out=out,
        robot=ds.meta.robot,
        on_trial=on_trial,
        base=physics,
    )
