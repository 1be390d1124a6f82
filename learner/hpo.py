"""Hyperparameter search for the evidential ensemble: TPE + Hyperband over k-fold CV.

The score of a trial is DESIGN.md's: the mean over ``folds`` cross-validation folds of the
minimum validation MSE over epochs (scaled label units, see :mod:`learner.model`). By default a
trial's folds train at once as one batched model and every epoch reports the mean over the
folds to Hyperband (:mod:`learner.hpo_objective`); a trial's epochs are capped by a work budget
that scales with the data and network size (:mod:`learner.hpo_config`). ``workers`` processes
on one machine, or any number on several machines sharing an RDB storage (PostgreSQL), run one
study together (:mod:`learner.hpo_study`, :mod:`learner.hpo_workers`).

Trial 0 is the learner's default configs, scored on the same folds. Among the ``top_k`` best
trials within ``select_within`` of the best score the one with the fewest weights is retrained
on all data as ``robocal train`` trains (validation split, best epoch, early stopping) and
written as a snapshot (:mod:`learner.snapshot`).
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import asdict, dataclass, field, fields
from pathlib import Path

import numpy as np
import torch
from optuna.trial import FrozenTrial, TrialState

from kinematics.dataset import Dataset
from kinematics.errors import ConfigError
from kinematics.identity import description_for
from kinematics.model import RobotModel
from learner.base import DEFAULT_BASE, PhysicsBase, data_frame, make_base
from learner.config import TrainConfig
from learner.features import FeatureSpec, dataset_feature_spec, dataset_features, dataset_labels
from learner.hpo_config import HpoConfig
from learner.hpo_lock import study_lock
from learner.hpo_objective import cv_folds, cv_objective, trial_configs
from learner.hpo_space import SearchSpace, TrialParams, learner_defaults
from learner.hpo_study import (
    Progress,
    run_trials,
    select_trial,
    top_trials,
)
from learner.hpo_workers import open_study, start_workers, wait_workers
from learner.model import ErrorModel
from learner.snapshot import save_snapshot

__all__ = ["HpoConfig", "HpoResult", "TrialRow", "cv_folds", "run_hpo", "search", "retrain"]


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
    workers: int
    worker_exit_codes: tuple[int, ...]
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
    workers: int = 1,
) -> HpoResult:
    """Run (or resume, or join) the study on ``storage`` up to ``cfg.trials`` trials, select
    among the best the smallest model, retrain it on all of ``X, Y`` and save it to ``out``.
    Every network learns the residual of ``base`` (None: the nominal). ``workers - 1`` helper
    processes run trials beside this one, each with this process's torch thread count."""
    if not isinstance(workers, int) or workers < 1:
        raise ConfigError(f"hpo workers must be an int >= 1, got {workers!r}")
    start = time.perf_counter()
    deadline = None if cfg.timeout_s is None else time.monotonic() + cfg.timeout_s
    study = open_study(cfg, storage)
    space = space or SearchSpace()
    helpers = start_workers(
        workers - 1,
        spec,
        X,
        Y,
        cfg,
        storage,
        space=space,
        base=base,
        deadline=deadline,
        threads=torch.get_num_threads(),
    )
    try:
        mine = run_trials(
            study,
            cv_objective(spec, X, Y, space, cfg, base, deadline),
            cfg.trials,
            timeout_s=cfg.timeout_s,
            lock=study_lock(storage, cfg.study),
            on_trial=on_trial,
            first=learner_defaults(space) if cfg.defaults_first else None,
        )
    except BaseException:
        wait_workers(helpers, stop=True)
        raise
    exit_codes = wait_workers(helpers)
    chosen = select_trial(study, cfg.top_k, cfg.select_within)
    model, epochs = retrain(spec, X, Y, TrialParams.from_dict(chosen.params), cfg, robot, base)
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
        workers=workers,
        worker_exit_codes=tuple(exit_codes),
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
    robot: str = "",
    base: PhysicsBase | None = None,
) -> tuple[ErrorModel, int]:
    """A fresh model of ``params`` on ``base`` trained on ``X, Y`` as ``robocal train`` trains
    (validation split, best epoch, early stopping), and its epochs. A trial's epochs are a
    screening budget, not a recipe: retrained for them, a 34-epoch trial gave 0.616 mm on the
    paper campaign where the same parameters trained to their best epoch gave 0.069 mm."""
    full = TrainConfig()
    model_cfg, train_cfg = trial_configs(params, cfg, full.max_epochs, full.val_fraction)
    model = ErrorModel.create(spec, model_cfg, train_cfg, seed=cfg.seed, robot=robot, base=base)
    torch.manual_seed(cfg.seed)  # dropout masks come from torch's global generator
    report = model.fit(X, Y)
    return model, report.epochs


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
    workers: int = 1,
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
        workers=workers,
    )
