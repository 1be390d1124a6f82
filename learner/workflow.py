"""Dataset-level workflows behind the CLI: batch training, continual streaming, evaluation.

Each takes a :class:`~kinematics.dataset.Dataset`, builds features and labels against the
nominal model (with the dataset's ``T_6_S`` when known, or the model's own nominal), splits off
a seeded test set, identifies the physics base on the training points only (:mod:`learner.base`)
and returns a typed result; the CLI writes models, states and curves (``stream.reports``).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field, replace

import numpy as np

from kinematics.dataset import Dataset
from kinematics.description import RobotDescription
from kinematics.errors import ConfigError, DatasetError, IdentifiabilityError
from kinematics.identity import check_match, description_for
from kinematics.model import RobotModel
from learner.base import (
    PhysicsBase,
    check_same_robot,
    data_frame,
    make_base,
    nominal_base,
)
from learner.carry import drift_scale
from learner.config import (
    SELECTED_BASE,
    ContinualConfig,
    ModelConfig,
    TrainConfig,
    is_model_file,
)
from learner.continual import ContinualLearner
from learner.continual_records import UpdateMetrics
from learner.features import FeatureSpec, dataset_feature_spec, dataset_features, dataset_labels
from learner.metrics import AccuracyReport, accuracy_report, past_envelope
from learner.model import ErrorModel, TrainReport


@dataclass(frozen=True, kw_only=True)
class Prepared:
    """Features, labels and the seeded train/test split of one dataset."""

    spec: FeatureSpec
    robot: str
    X: np.ndarray
    Y: np.ndarray
    train: np.ndarray
    test: np.ndarray


def nominal_description(ds: Dataset) -> RobotDescription:
    """The dataset's robot description, with its ``T_6_S`` when the metadata knows it."""
    desc = description_for(ds)
    return desc if ds.meta.T_6_S is None else desc.with_tool(np.asarray(ds.meta.T_6_S))


def prepare(
    ds: Dataset,
    *,
    test_fraction: float = 0.1,
    seed: int = 0,
    secondary: bool = True,
    temperatures: bool = True,
    spec: FeatureSpec | None = None,
) -> Prepared:
    """Features (all the dataset has, or a subset), labels and a random split. With ``spec`` (a
    model's), the labels are against the model's nominal description."""
    if not 0.0 <= test_fraction < 1.0:
        raise ConfigError(f"test_fraction must be in [0, 1), got {test_fraction}")
    desc = nominal_description(ds)
    if spec is not None and spec.description is not None:
        check_same_robot(spec.description, desc, "the model")
        desc = spec.description
    spec = spec or dataset_feature_spec(ds, desc, secondary=secondary, temperatures=temperatures)
    X = dataset_features(ds, spec)
    Y = dataset_labels(ds, RobotModel(desc))
    order = np.random.default_rng(seed).permutation(len(ds))
    n_test = round(test_fraction * len(ds))
    if len(ds) - n_test < 10:
        raise DatasetError(f"need at least 10 training points, got {len(ds) - n_test}")
    return Prepared(
        spec=spec, robot=desc.name, X=X, Y=Y, train=order[n_test:], test=np.sort(order[:n_test])
    )


def _new_model(
    p: Prepared,
    model_cfg: ModelConfig | None,
    train_cfg: TrainConfig | None,
    seed: int,
    base: PhysicsBase | None,
) -> ErrorModel:
    """A fresh model for prepared data (default configs where none is given)."""
    return ErrorModel.create(
        p.spec, model_cfg or ModelConfig(), train_cfg or TrainConfig(seed=seed), seed, p.robot, base
    )


@dataclass(frozen=True, kw_only=True)
class TrainResult:
    """The trained model, its training and test reports, and a continual learner whose memory
    is the worst-predicted training points (saved beside the model, ``continual --from``)."""

    model: ErrorModel
    report: TrainReport
    test: AccuracyReport | None
    n_train: int
    learner: ContinualLearner


#: A base with fitted effects is kept over a simpler one only when its validation error is below
#: this share of the simpler one's: a tie keeps the simpler base. It was 0.8 while fitted
#: effects extrapolated without a prior (UR10 B's gap model carried to A: 2.0 mm, the geometric
#: base 0.55 mm); under the calibration prior that model carries as well (0.61 mm after 100 of
#: A's points, 0.64 against 0.75 mm after 10), and 0.95 keeps the better base on all 16 random
#: arms of ``bench/learner_unseen.py`` (BENCHMARKS.md, "robocal train --base best").
MORE_PHYSICS_MUST_WIN = 0.95


def train_on_dataset(
    ds: Dataset,
    *,
    test_fraction: float = 0.1,
    seed: int = 0,
    model_cfg: ModelConfig | None = None,
    train_cfg: TrainConfig | None = None,
    on_epoch: Callable[[int, float], None] | None = None,
    base: str = SELECTED_BASE,
) -> TrainResult:
    """Batch-train a model on ``base`` (identified on the training split), measure how much
    wider its intervals must be on a later day (:func:`~learner.carry.drift_scale`) and report
    its test accuracy; the result's learner remembers the worst-predicted training points. ``best``
    (:data:`SELECTED_BASE`) trains one on the geometric and one on the gap base and keeps the
    gap one only where it predicts the validation points (those :meth:`ErrorModel.fit` held
    out) clearly better (:func:`best_on_validation`)."""
    p = prepare(ds, test_fraction=test_fraction, seed=seed)
    train = np.sort(p.train)
    fits = []
    for physics in _candidate_bases(base, p, train, data_frame(ds)):
        model = _new_model(p, model_cfg, train_cfg, seed, physics)
        fits.append((model, model.fit(p.X[p.train], p.Y[p.train], on_epoch=on_epoch)))
    model, report = best_on_validation(fits, p.X[p.train], p.Y[p.train])
    times = ds.table["t"].to_numpy(float)[train]
    model.drift_scale = drift_scale(model, p.X[train], p.Y[train], times, on_epoch)
    test = accuracy_report(model, p.X[p.test], p.Y[p.test]) if len(p.test) else None
    model.metrics = {} if test is None else test.to_dict()
    learner = ContinualLearner(model, ContinualConfig(seed=seed))
    learner.remember(p.X[train], p.Y[train])
    return TrainResult(model=model, report=report, test=test, n_train=len(p.train), learner=learner)


def _candidate_bases(
    base: str, p: Prepared, train: np.ndarray, frame: np.ndarray | None
) -> list[PhysicsBase]:
    """The bases to train on: ``base``'s, or for ``best`` the geometric and the gap base. The
    gap base is left out, and the note says why, where it names nothing beyond the geometry
    (the same base: not trained twice) or the data cannot form it (e.g. thermometers the
    description's map names are missing); both, for the nominal, where the points cannot
    identify a calibration."""
    X, Y = p.X[train], p.Y[train]
    if base != SELECTED_BASE:
        return [make_base(base, p.spec, X, Y, frame)]
    try:
        geometric = make_base("geometric", p.spec, X, Y, frame)
    except IdentifiabilityError as exc:  # too few points or a joint that never moves
        return [replace(nominal_base(p.spec.description), note=f"nominal: {exc}")]
    try:
        gap = make_base("gap", p.spec, X, Y, frame)
    except (DatasetError, IdentifiabilityError) as exc:  # e.g. its own split leaves too few
        return [replace(geometric, note=f"{geometric.note}; no gap base: {exc}")]
    if not any(e.name != "geometric" for e in gap.effects):
        return [replace(geometric, note=f"{geometric.note}; the gap model names no effect")]
    return [geometric, gap]


def best_on_validation(
    fits: list[tuple[ErrorModel, TrainReport]], X: np.ndarray, Y: np.ndarray
) -> tuple[ErrorModel, TrainReport]:
    """Of models fitted on ``X, Y``, simplest base first, the first that no later one beats by
    :data:`MORE_PHYSICS_MUST_WIN` in mean position error on the points its fit held out (the
    same for all: same seeds); its base note gives every error."""
    if len(fits) == 1:
        return fits[0]
    held = fits[0][0].validation_rows(len(X))
    if not len(held):
        raise DatasetError(
            f"base {SELECTED_BASE!r} needs validation points (>= 10 training points)"
        )
    errors = [accuracy_report(m, X[held], Y[held]).mean_mm for m, _ in fits]
    best = 0
    for i, error in enumerate(errors):
        best = i if error < MORE_PHYSICS_MUST_WIN * errors[best] else best
    model = fits[best][0]
    scores = ", ".join(f"{m.base.kind} {e:.4f} mm" for (m, _), e in zip(fits, errors, strict=True))
    note = f"{model.base.note}; chosen on {len(held)} validation points ({scores})"
    model.base = replace(model.base, note=note)
    return fits[best]


@dataclass(frozen=True, kw_only=True)
class ContinualResult:
    """The final model, the learner that trained it (config, memory, points seen) and the
    learning curve: one row per update with test accuracy."""

    model: ErrorModel
    learner: ContinualLearner
    updates: list[UpdateMetrics]
    curve: list[dict] = field(default_factory=list)
    test: AccuracyReport | None = None
    total_time_s: float = 0.0
    #: With a carried learner: the share of the day's poses past its model's envelope at start.
    day_past_envelope: float | None = None


def continual_on_dataset(
    ds: Dataset,
    cfg: ContinualConfig,
    *,
    test_fraction: float = 0.1,
    seed: int = 0,
    model_cfg: ModelConfig | None = None,
    train_cfg: TrainConfig | None = None,
    on_update: Callable[[UpdateMetrics], None] | None = None,
    base: str | None = None,
    start: ContinualLearner | None = None,
) -> ContinualResult:
    """Stream the training split in its recorded order through a :class:`ContinualLearner`
    (``init`` points first, then batches of ``cfg.batch``), evaluating the test split after
    every update. ``base`` is ``cfg.base`` or a model file. With ``start`` (a learner carried
    from another day, :func:`load_learner`) its frames are re-identified and its network
    weighed from the first ``init`` points before they are learned
    (:meth:`ContinualLearner.carry`), and the share of the day's poses past the joint angles
    its model was trained on is reported."""
    if start is None:
        p = prepare(ds, test_fraction=test_fraction, seed=seed)
        cfg = cfg if base is None else replace(cfg, base=base)
        physics = None  # identified by the learner from its first points
        if is_model_file(cfg.base):  # fitted to them where it leaves effects out
            physics = make_base(cfg.base, p.spec, p.X[:0], p.Y[:0], data_frame(ds))
        learner = ContinualLearner(_new_model(p, model_cfg, train_cfg, seed, physics), cfg)
    else:
        learner = start
        p = prepare(ds, test_fraction=test_fraction, seed=seed, spec=learner.model.spec)
    train = np.sort(p.train)
    Xtr, Ytr = p.X[train], p.Y[train]
    day_past = None
    if start is not None:
        day_past = float(past_envelope(learner.model, p.X).mean())
        learner.carry(Xtr[: cfg.init], Ytr[: cfg.init])
    Xte, Yte = p.X[p.test], p.Y[p.test]
    updates, curve = [], []
    for m in learner.learn_stream(Xtr, Ytr):
        updates.append(m)
        row = {**m.to_dict()}
        if len(Xte):
            row.update(accuracy_report(learner.model, Xte, Yte).to_dict())
        curve.append(row)
        if on_update is not None:
            on_update(m)
    test = accuracy_report(learner.model, Xte, Yte) if len(Xte) else None
    learner.model.metrics = {} if test is None else test.to_dict()
    return ContinualResult(
        model=learner.model,
        learner=learner,
        updates=updates,
        curve=curve,
        test=test,
        total_time_s=float(sum(u.train_time_s for u in updates)),
        day_past_envelope=day_past,
    )


def evaluate_on_dataset(model: ErrorModel, ds: Dataset) -> AccuracyReport:
    """Accuracy of a trained model on every point of ``ds`` (features by the model's names)."""
    return accuracy_report(model, *evaluation_points(model, ds))


def evaluation_points(model: ErrorModel, ds: Dataset) -> tuple[np.ndarray, np.ndarray]:
    """Features and labels of every point of ``ds``, once it is checked to be the model's robot."""
    if model.spec.description is not None:
        check_match(model.spec.description, ds)
    elif ds.meta.robot != model.robot and model.robot:
        raise DatasetError(f"model is for robot {model.robot!r}, dataset is {ds.meta.robot!r}")
    p = prepare(ds, test_fraction=0.0, spec=model.spec)
    return p.X, p.Y
