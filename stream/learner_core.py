"""The learner stage's logic without I/O: batches in, model updates and metrics out.

Every batch is first screened by the learner's quarantine
(:meth:`learner.continual.ContinualLearner.screen`): a poisoned point is neither tested on nor
learned. Of the points that pass, every ``holdout_every``-th (by arrival) joins a held-out
test set (the newest ``max_test_points``) that is never trained on; the rest go to
:meth:`learner.continual.ContinualLearner.update`. After each update the core reports test
error and uncertainty (:mod:`learner.holdout`), the prequential batch error and the memory
composition by batch age. Its checkpoint (learner state + test set + counters, safetensors
with JSON metadata) is built and read as bytes here; the learner stage writes and reads the file
(:mod:`stream.stages.learner_stage`), so a restart continues without losing accepted data.
Batches already learned (by ``seq``) are refused as duplicates. A batch that comes more than
``new_day_after_h`` (off by default) after the latest learned point starts a new day, carried
into it as a model file is (:meth:`learner.continual.ContinualLearner.carry`).
"""

from __future__ import annotations

import json
import time
from collections.abc import Sequence
from dataclasses import dataclass, field, replace

import numpy as np
from safetensors import SafetensorError
from safetensors.numpy import load as np_load
from safetensors.numpy import save as np_save

from kinematics.dataset import temperature_column, temperature_columns
from kinematics.description import RobotDescription
from kinematics.errors import ConfigError, RobocalError, SnapshotError
from kinematics.gap.model_file import load_model_file
from kinematics.model import RobotModel
from learner.base import PhysicsBase, check_same_robot, file_base
from learner.carry import before_day
from learner.config import ContinualConfig, ModelConfig, TrainConfig, is_model_file
from learner.continual import ContinualLearner, load_learner
from learner.continual_records import UpdateMetrics
from learner.continual_state import state_from_bytes, state_to_bytes
from learner.features import FeatureSpec, feature_spec
from learner.holdout import HeldOut, MemoryAge, heldout_metrics, holdout_mask
from learner.model import ErrorModel
from learner.snapshot import load_snapshot, read_metadata, snapshot_from_bytes, snapshot_to_bytes
from learner.training import Trainer
from stream.points import point_arrays
from wire import Batch, Metrics, ModelHeader, RejectedMessageError

CHECKPOINT_SCHEMA = "robocal.learner_stage"


@dataclass(frozen=True, kw_only=True)
class LearnerStageConfig:
    """Model, training and continual configs, the hold-out rate and the feature subset."""

    model: ModelConfig = field(default_factory=ModelConfig)
    train: TrainConfig = field(default_factory=TrainConfig)
    continual: ContinualConfig = field(default_factory=ContinualConfig)
    holdout_every: int = 10
    max_test_points: int = 1000
    seed: int = 0
    use_secondary: bool = True
    use_temperatures: bool = True
    #: A model file to go on from (with its replay memory when its state is beside it); its
    #: frames are re-identified from the first batch, as ``robocal continual --from`` does.
    start_from: str | None = None
    #: Train in a child process (:mod:`learner.train_process`, about 0.4 GB): the stages keep
    #: the interpreter and the model trains on another core; the same weights either way.
    train_process: bool = True
    #: A pause between two batches' points longer than this (h) starts a new day: its first
    #: batch carries the model as ``start_from`` does (frames checked, intervals as wide as
    #: its drift scale, the day's own held-out points), and a model restored after such a
    #: pause is published as :func:`~learner.carry.before_day` until then. Off (``inf``) by
    #: default: on UR10 Series A (one tracker set-up, days 5.6-21 h apart) 4 h made the days'
    #: first batches 0.70 mm instead of 0.54 mm and the stream 1.7 x slower (BENCHMARKS.md, "A
    #: new day before any of its points"); set it where the tracker is set up again each day.
    new_day_after_h: float = float("inf")

    def __post_init__(self) -> None:
        if not (isinstance(self.holdout_every, int) and self.holdout_every >= 2):
            raise ConfigError(
                f"learner.holdout_every must be an int >= 2, got {self.holdout_every}"
            )
        if not self.new_day_after_h > 0:
            raise ConfigError(f"learner.new_day_after_h must be > 0 h, got {self.new_day_after_h}")


@dataclass(frozen=True)
class Update:
    """One published model: its header, snapshot bytes (safetensors) and metrics."""

    header: ModelHeader
    snapshot: bytes
    metrics: Metrics


def check_thermometers(path: str, names: Sequence[str]) -> None:
    """ConfigError where the model file ``path`` (``learner.start_from``) reads a thermometer
    that none of ``names`` (the window's pinned channels) gives: each of its batches would be
    refused as ``features``."""
    given = {temperature_column(n) for n in names}
    missing = [c for c in temperature_columns(load_snapshot(path).spec.names) if c not in given]
    if missing:
        raise ConfigError(
            f"learner.start_from {path}: its model reads {', '.join(missing)}, which "
            f"window.temperature_names ({', '.join(names)}) does not give"
        )


class LearnerCore:
    """Turns batches of one robot into model updates (see the module docstring)."""

    def __init__(
        self, desc: RobotDescription, cfg: LearnerStageConfig, T_W_0: np.ndarray | None = None
    ) -> None:
        self.desc, self.cfg = desc, cfg
        self.robot = RobotModel(desc)
        self.T_W_0 = None if T_W_0 is None else np.asarray(T_W_0, dtype=float)
        self.learner: ContinualLearner | None = None
        #: What runs the learner's training loops (None: this thread; the stage: a process).
        self.trainer: Trainer | None = None
        self.test: HeldOut | None = None
        self._reidentify = False
        if cfg.start_from:
            self._start_from(cfg.start_from)
        elif is_model_file(cfg.continual.base):  # stops at the start, not at the first batch
            path = cfg.continual.base
            check_same_robot(load_model_file(path).description, desc, f"base file {path}")
        self.last_seq = -1
        self.n_points = 0
        #: The latest learned point's time (s, the points' clock; None before one).
        self.last_t: float | None = None
        #: What the learner did with the latest batch (None while a batch is refused).
        self.last_step: UpdateMetrics | None = None
        self.age = MemoryAge()
        #: Per window run (epoch): its last batch seq learned and the index of the next point
        #: expected; kept with the checkpoint so a restarted window's batches go on (the stage).
        self.windows: dict[int, tuple[int, int]] = {}

    @property
    def test_x(self) -> np.ndarray:
        """Features of the held-out test points (empty before the first batch)."""
        return np.empty((0, 0)) if self.test is None else self.test.x

    @property
    def test_y(self) -> np.ndarray:
        """Labels of the held-out test points (m, rad)."""
        return np.empty((0, 6)) if self.test is None else self.test.y

    def spec_for(self, batch: Batch) -> FeatureSpec:
        p = batch.points[0]
        names = p.temperature_names if self.cfg.use_temperatures else ()
        has_sec = self.cfg.use_secondary and p.qs is not None
        return feature_spec(self.desc, len(names), has_sec, names)

    def features(self, batch: Batch) -> tuple[np.ndarray, np.ndarray]:
        """Raw features and labels of a batch's points (SI)."""
        try:
            arrays = point_arrays(batch.points, self.T_W_0)
            spec = self.spec_for(batch) if self.learner is None else self.learner.model.spec
            return arrays.features(spec), arrays.labels(self.robot)
        except RobocalError as exc:
            raise RejectedMessageError("features", f"batch {batch.seq}: {exc}") from None

    def add_batch(self, batch: Batch, now: float | None = None) -> Update | None:
        """Learn one batch; the published update, or None while collecting the first points.
        A batch across a new day's pause is learned as two: the old day's points, then the
        new day's, carried into it."""
        self.last_step = None
        if batch.seq <= self.last_seq:
            raise RejectedMessageError("duplicate", f"batch {batch.seq} already learned")
        if not batch.points:
            raise RejectedMessageError("malformed", f"batch {batch.seq} has no points")
        X, Y = self.features(batch)
        if not (np.isfinite(X).all() and np.isfinite(Y).all()):
            raise RejectedMessageError("non_finite", f"batch {batch.seq}: non-finite features")
        t, spec = np.array([p.t for p in batch.points]), self.spec_for(batch)
        cut = self._new_day_at(t)
        self.last_seq, update = batch.seq, None
        if cut:  # the old day's last points first
            update = self._learn(X[:cut], Y[:cut], spec, t[cut - 1], now)
        if cut is not None and self.learner is not None and self.learner.model.is_fitted:
            self._reidentify = True  # carried into the new day as a model file is
            self.test = HeldOut(self.learner.model.spec.n_features, self.cfg.max_test_points)
        cut = cut or 0
        last = self._learn(X[cut:], Y[cut:], spec, t[-1], now, self.last_step)
        self.last_t = float(t.max())
        return last or update

    def _new_day_at(self, t: np.ndarray) -> int | None:
        """The index of a batch's first point (times ``t``, s) after a pause of more than
        ``new_day_after_h`` from the point before it (the latest learned, for the first)."""
        before = np.concatenate([[np.inf if self.last_t is None else self.last_t], t[:-1]])
        pauses = np.flatnonzero(t - before > 3600.0 * self.cfg.new_day_after_h)
        return int(pauses[0]) if len(pauses) else None

    def _learn(
        self,
        X: np.ndarray,
        Y: np.ndarray,
        spec: FeatureSpec,
        t: float,
        now: float | None,
        earlier: UpdateMetrics | None = None,
    ) -> Update | None:
        """Screen, hold out and learn the points ``X, Y`` of the latest batch (the last at
        ``t``, s; ``spec``: its features for a first model; ``earlier``: what its points before
        a new day's pause did)."""
        if self._reidentify:  # a carried model's first batch: this cell's frames and trust
            self.learner.carry(X, Y)
            self._reidentify = False
        if self.learner is None:
            base = self._file_base(spec)
            model = ErrorModel.create(
                spec, self.cfg.model, self.cfg.train, self.cfg.seed, self.desc.name, base
            )
            self.learner = ContinualLearner(model, self.cfg.continual)
            self.test = HeldOut(X.shape[1], self.cfg.max_test_points)
        passed = self.learner.screen(X, Y)
        test = holdout_mask(self.n_points, len(X), self.cfg.holdout_every) & passed
        train = ~test & passed
        self.test.add(X[test], Y[test])
        self.age.record(X[train], self.last_seq)
        self.n_points += len(X)
        version = self.learner.version
        self.learner.trainer = self.trainer  # however the learner came: new, file, checkpoint
        m = self.learner.update(X[train], Y[train], screened=True)
        quarantined = int((~passed).sum()) + (0 if earlier is None else earlier.quarantined)
        self.last_step = replace(m, quarantined=quarantined)
        if self.learner.version == version:
            return None
        self.age.keep(self.learner.memory.x)
        metrics = self.metrics(m.batch_mean_mm, m.train_time_s, now)
        return self.published(float(t), metrics)

    def paused(self, t: float) -> bool:
        """Whether time ``t`` (s) comes more than ``new_day_after_h`` after the latest learned
        point: a new day, that no point has checked the model on yet."""
        return self.last_t is not None and t - self.last_t > 3600.0 * self.cfg.new_day_after_h

    def published(self, t: float, metrics: Metrics, new_day: bool = False) -> Update:
        """The update message of the published model, stamped ``t`` (s); on a ``new_day``
        before any of its points, as :func:`~learner.carry.before_day` serves it."""
        learner = self.learner
        header = ModelHeader(
            model_version=learner.version, robot=self.desc.name, n_seen=learner.n_seen, t=t
        )
        model = before_day(learner.model) if new_day else learner.model
        snap = snapshot_to_bytes(model, {"model_version": learner.version})
        return Update(header, snap, metrics)

    def metrics(self, batch_mean_mm: float, train_time_s: float, now: float | None) -> Metrics:
        """The metrics message of the published model (test set, memory, counters)."""
        learner = self.learner
        test = heldout_metrics(learner.model, self.test.x, self.test.y)
        return Metrics(
            model_version=learner.version,
            n_seen=learner.n_seen,
            memory_size=len(learner.memory),
            train_time_s=train_time_s,
            test_mean_mm=test.mean_mm,
            test_max_mm=test.max_mm,
            batch_mean_mm=batch_mean_mm,
            aleatoric_mm=test.aleatoric_mm,
            epistemic_mm=test.epistemic_mm,
            epistemic_p90_mm=test.epistemic_p90_mm,
            memory_age=self.age.histogram(learner.memory.x, self.last_seq),
            quarantined=learner.quarantine.quarantined,
            withheld=learner.n_withheld,
            t=time.time() if now is None else now,
        )

    def _file_base(self, spec: FeatureSpec) -> PhysicsBase | None:
        """The model file ``continual.base`` names as the base (None: a kind the learner
        identifies), its ``T_W_0`` against this cell's tracker; a stream without a thermometer
        the file's effects need is refused batch by batch."""
        path = self.cfg.continual.base
        if not is_model_file(path):
            return None
        frame = np.eye(4) if self.T_W_0 is None else self.T_W_0
        try:
            return file_base(path, spec, frame)
        except ConfigError as exc:
            raise RejectedMessageError("features", str(exc)) from None

    def checkpoint(self) -> bytes | None:
        """The learner state, test set and counters as safetensors bytes (None before a model)."""
        if self.learner is None:
            return None
        meta = {
            "schema": CHECKPOINT_SCHEMA,
            "last_seq": self.last_seq,
            "n_points": self.n_points,
            "last_t": self.last_t,
            "windows": [[e, s, f] for e, (s, f) in self.windows.items()],
            "state": state_to_bytes(self.learner.state_dict()).hex(),
        }
        rows, ages = self.age.arrays()
        return np_save(
            {"test_x": self.test.x, "test_y": self.test.y, "age_rows": rows, "ages": ages},
            metadata={"robocal": json.dumps(meta)},
        )

    def _start_from(self, path: str) -> None:
        """Go on from a model file of this robot (ConfigError naming a mismatch)."""
        learner = load_learner(path, self.cfg.continual)
        check_same_robot(learner.model.spec.description, self.desc, f"model {path}")
        self.learner, self._reidentify = learner, True
        self.robot = RobotModel(learner.model.spec.description)  # labels against its nominal
        self.test = HeldOut(learner.model.spec.n_features, self.cfg.max_test_points)

    def restore(self, data: bytes) -> None:
        """Continue from :meth:`checkpoint` bytes (SnapshotError when they are not one)."""
        try:
            arrays = np_load(data)
            meta = read_metadata(data)
            if meta.get("schema") != CHECKPOINT_SCHEMA:
                raise SnapshotError(f"schema {meta.get('schema')!r} is not a checkpoint")
            state = state_from_bytes(bytes.fromhex(meta["state"]))
        except (SafetensorError, ValueError, KeyError, TypeError) as exc:
            raise SnapshotError(f"unreadable checkpoint: {exc}") from None
        model = snapshot_from_bytes(state["model"])
        self.learner = ContinualLearner(model, self.cfg.continual)
        self.learner.load_state(state)
        self.robot = RobotModel(model.spec.description or self.desc)
        self._reidentify = False  # the checkpoint is of this cell already
        self.test = HeldOut(model.spec.n_features, self.cfg.max_test_points)
        self.test.add(arrays["test_x"], arrays["test_y"])
        self.last_seq, self.n_points = int(meta["last_seq"]), int(meta["n_points"])
        self.last_t = None if meta.get("last_t") is None else float(meta["last_t"])
        self.windows = {int(e): (int(s), int(f)) for e, s, f in meta.get("windows", [])}
        self.age = MemoryAge.from_arrays(arrays["age_rows"], arrays["ages"])
