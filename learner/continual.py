"""Continual learning by max-error replay (DESIGN.md) and its baselines, one batch at a time.

Each :meth:`ContinualLearner.update` predicts memory ∪ new batch with the current model, ranks
the pool by the Euclidean norm of the prediction error (in standardised label units, so
position and orientation count alike), lets the replay strategy pick the new memory and trains
the model warm-started on it, its rate annealed from ``update_lr`` to 0. A ``holdout`` share of
every batch never enters the pool: it joins a first-in-first-out set of the latest
``calibration_size`` such points, on which the intervals are calibrated after each training —
data the model was never trained on (calibrating on the new batch before training on it let
the 90 % coverage swing between 73 % and 95 %); it also chooses which epoch's weights an
update keeps. Until ``init`` points have arrived, updates only collect points.

Poisoned measurements are kept out (:mod:`learner.quarantine`): every new point is screened
against the published model and its neighbours first; a quarantined point is neither trained
on, held out nor kept. An update whose published model is worse on the held-out set than the
last by more than ``quarantine.publish_tolerance`` is withheld.

The model the learner publishes (:attr:`ContinualLearner.model`) is not the trained one
(:attr:`ContinualLearner.trained`) but an exponential moving average of its weights over
updates, the latest update's share ``average``: it keeps what the earlier memories taught
(BENCHMARKS.md, "Continual updates annealed"). Ranking and training use the trained weights.
With ``refresh_growth`` (off by default) a fresh network is trained on the memory as the
stream grows and kept where it predicts the held-out set better (:mod:`learner.refresh`); on a
carried day ``day_refresh_growth`` (on) does so as the day's own points grow.
"""

from __future__ import annotations

import time
from collections.abc import Iterator
from dataclasses import replace
from pathlib import Path

import numpy as np
import torch

from learner import continual_day
from learner.base import PhysicsBase, identify_base, nominal_base
from learner.carry import MIN_DAY_POINTS, CarriedDay, hold_day
from learner.config import ContinualConfig
from learner.conformal import adapt_log_scale, take_up
from learner.continual_base import REFINED, doubled, due, memory_base, refined_base, status
from learner.continual_records import Memory, UpdateMetrics, checked_batch, memory_mm
from learner.continual_state import learner_state, restore_learner, state_from_bytes, state_path
from learner.metrics import interval_coverage
from learner.model import MIN_CALIBRATION, ErrorModel
from learner.quarantine import QuarantineState, holdout_mm, model_residuals, screen, withhold
from learner.refresh import fresh_fit, refresh_due
from learner.replay import replay_strategy
from learner.snapshot import copy_model, load_snapshot
from learner.training import Trainer, TrainReport


class ContinualLearner:
    """Learns one batch at a time with a fixed-size replay memory; publishes :attr:`model`,
    the moving average of the :attr:`trained` weights."""

    def __init__(self, model: ErrorModel, cfg: ContinualConfig) -> None:
        self.model = model
        self.trained = model  # a copy of its own from the first model on
        self.cfg = cfg
        self.aci_log_scale = np.zeros(6)
        self.strategy = replay_strategy(cfg.strategy)
        self.rng = np.random.default_rng(cfg.seed)
        n_f = model.spec.n_features
        self._mem_x, self._mem_y = np.empty((0, n_f)), np.empty((0, 6))
        self._cal_x, self._cal_y = np.empty((0, n_f)), np.empty((0, 6))
        self.n_seen, self.version = 0, 0
        self.quarantine = QuarantineState.empty()
        self.n_withheld = 0
        #: A carried day's last interval scale before ACI: while the day is young the one it
        #: came with (:meth:`carry`), then its last calibration (:meth:`_scale`).
        self.day_scale: np.ndarray | None = None
        self.day: CarriedDay | None = None  # a carried day's points, its frames fitted again
        self.trainer: Trainer | None = None  # runs its fits (None: here; stream: a process)
        if model.is_fitted:  # a trained model (a snapshot) goes on learning with an empty memory
            self.trained = copy_model(model)
            self.version = 1

    @property
    def base(self) -> PhysicsBase:
        """The physics base the learner's models stand on (the nominal until identified)."""
        return self.trained.base or nominal_base(self.trained.spec.description)

    @property
    def memory(self) -> Memory:
        return Memory(self._mem_x.copy(), self._mem_y.copy())

    def screen(self, X: np.ndarray, Y: np.ndarray) -> np.ndarray:
        """Which new points pass the quarantine (bool per row); counted in :attr:`quarantine`."""
        X, Y = checked_batch(X, Y, self.model.spec.n_features)
        r, z = model_residuals(self.model, X, Y)
        accepted, self.quarantine = screen(Y, r, z, self.quarantine, self.cfg.quarantine)
        return accepted

    def initialize(self, X: np.ndarray, Y: np.ndarray, screened: bool = False) -> UpdateMetrics:
        """Train the first model on those of ``X, Y`` (normally the first ``init`` points) that
        pass the quarantine (all when ``screened`` already)."""
        X, Y = checked_batch(X, Y, self.model.spec.n_features)
        n_in = len(X)
        ok = np.ones(n_in, dtype=bool) if screened else self.screen(X, Y)
        X, Y = X[ok], Y[ok]
        self._mem_x, self._mem_y = X[-self.cfg.memory :], Y[-self.cfg.memory :]
        self.n_seen = n_in
        start = time.perf_counter()
        if self.trained.base is None and self.trained.spec.description is not None:
            self.trained.base = identify_base(self.cfg.base, self.trained.spec, X, Y)
        elif status(self.base) == "refitted":  # a model file's base: fitted to this stream
            self.trained.base = refined_base(self.base, self.trained.spec, X, Y) or self.base
        report = self.trained.fit(X, Y, max_epochs=self.cfg.init_epochs, trainer=self.trainer)
        self.model = copy_model(self.trained)
        self.version += 1
        m = self._metrics(len(X), len(self._mem_x), report, time.perf_counter() - start)
        return replace(m, quarantined=int(n_in - ok.sum()))

    def learn_stream(self, X: np.ndarray, Y: np.ndarray) -> Iterator[UpdateMetrics]:
        """Learn ``X, Y`` in their order, as a line delivers them: the first model from the
        first ``init`` points (unless it has one already), then one :meth:`update` per ``batch``
        points; yields each step's metrics."""
        init, batch = (0 if self.version else self.cfg.init), self.cfg.batch
        if init:
            yield self.initialize(X[:init], Y[:init])
        for i in range(init, len(X), batch):
            yield self.update(X[i : i + batch], Y[i : i + batch])

    def update(self, X_new: np.ndarray, Y_new: np.ndarray, screened: bool = False) -> UpdateMetrics:
        """Learn one batch: keep out what the quarantine refuses (unless ``screened`` already),
        hold out a share for calibration, select the memory from memory ∪ the rest, train on
        it, recalibrate the intervals on the held-out set; publish unless the gate withholds."""
        X_new, Y_new = checked_batch(X_new, Y_new, self.model.spec.n_features)
        n_in = len(X_new)
        ok = np.ones(n_in, dtype=bool) if screened else self.screen(X_new, Y_new)
        X_new, Y_new, out = X_new[ok], Y_new[ok], {"quarantined": int(n_in - ok.sum())}
        before = self.n_seen
        seen = before + n_in  # held-out and quarantined points included: every point given
        if self.version == 0:  # collecting the first points; the first model once there
            pool_x = np.concatenate([self._mem_x, X_new])
            pool_y = np.concatenate([self._mem_y, Y_new])
            if len(pool_x) >= self.cfg.init:
                m = self.initialize(pool_x, pool_y, screened=True)
                self.n_seen = seen
                return replace(m, n_seen=seen, **out)
            self._mem_x, self._mem_y = pool_x, pool_y
        if self.version == 0 or not len(X_new):  # nothing to learn yet
            self.n_seen = seen
            return replace(self._metrics(n_in, 0, None, 0.0), **out)
        covered = self._adapt_intervals(X_new, Y_new)
        n_new = len(X_new)
        held = np.zeros(n_new, dtype=bool)
        held[self.rng.permutation(n_new)[: int(self.cfg.holdout * n_new)]] = True
        keep_last = self.cfg.calibration_size
        self._cal_x = np.concatenate([self._cal_x, X_new[held]])[-keep_last:]
        self._cal_y = np.concatenate([self._cal_y, Y_new[held]])[-keep_last:]
        X_new, Y_new = X_new[~held], Y_new[~held]
        continual_day.follow(self, X_new, Y_new)
        pool_x = np.concatenate([self._mem_x, X_new])
        pool_y = np.concatenate([self._mem_y, Y_new])
        pred = self.trained.predict(pool_x).gamma
        errors = np.linalg.norm((pred - pool_y) / self.trained.label_std, axis=1)
        keep = self.strategy.select(
            errors, self.cfg.memory, self.rng, n_new=len(X_new), n_seen=self.n_seen
        )
        keep = np.sort(keep)
        self._refine_base(len(self._mem_x), pool_x, pool_y, len(keep) == len(pool_x))
        self._mem_x, self._mem_y = pool_x[keep], pool_y[keep]
        self.n_seen = seen
        # The held-out set also picks the best epoch (and fit calibrates on it).
        val = (self._cal_x, self._cal_y) if len(self._cal_x) >= MIN_CALIBRATION else (None, None)
        mem, epochs = (self._mem_x, self._mem_y), self.cfg.update_epochs(len(self._mem_x))
        fit = {"val_fraction": 0.0, "lr": self.cfg.update_lr, "trainer": self.trainer}
        start = time.perf_counter()
        report = self.trained.fit(*mem, *val, max_epochs=epochs, anneal=True, **fit)
        withheld, holdout_mm = self._publish_gated()
        self._reidentify()
        self._refresh(before)
        new_kept = int(np.sum(keep >= len(pool_x) - len(X_new)))
        batch_err = np.linalg.norm((pred - pool_y)[-len(X_new) :, :3], axis=1)
        dt = time.perf_counter() - start
        m = self._metrics(len(X_new), new_kept, report, dt, batch_err)
        return replace(
            m, withheld=withheld, holdout_mm=holdout_mm, batch_coverage_90=covered, **out
        )

    def _refine_base(self, before: int, X: np.ndarray, Y: np.ndarray, all_kept: bool) -> None:
        """Identify the base again from every trained point ``X, Y`` each time they double, while
        the memory still holds them all (not on a carried day: its frames follow the day)."""
        grown = doubled(before, len(X), self.cfg.init)
        if all_kept and grown and self.day is None and status(self.base) in REFINED:
            base = refined_base(self.base, self.model.spec, X, Y)
            self.model.base = self.trained.base = base or self.base  # None: ill-conditioned

    def _reidentify(self) -> None:
        """Retrain on the base the memory identifies when due (:mod:`learner.continual_base`);
        publish it if the held-out error falls."""
        if len(self._cal_x) < MIN_CALIBRATION or not due(self.version, self.base):
            return
        base = memory_base(self.base, self.trained.spec, self._mem_x, self._mem_y)
        if base is None:
            return
        new = copy_model(self.trained)
        new.base, mem, cal = base, (self._mem_x, self._mem_y), (self._cal_x, self._cal_y)
        epochs, trainer = self.cfg.init_epochs, self.trainer
        new.fit(*mem, *cal, max_epochs=epochs, val_fraction=0.0, trainer=trainer)
        self._adopt(new)

    def _refresh(self, before: int) -> None:
        """A fresh network on the memory when :func:`~learner.refresh.refresh_due` (the points
        given, or a carried day's own, grew), kept if the held-out error falls."""
        day_start = None if self.day is None else self.day.seen_before
        if refresh_due(self.cfg, day_start, before, self.n_seen, len(self._cal_x)):
            mem, cal = (self._mem_x, self._mem_y), (self._cal_x, self._cal_y)
            self._adopt(fresh_fit(self.trained, *mem, *cal, self.trainer))

    def _adopt(self, new: ErrorModel) -> None:
        """Train on and publish ``new`` where it predicts the held-out set better."""
        cal = (self._cal_x, self._cal_y)
        if holdout_mm(new, *cal) < holdout_mm(self.model, *cal):
            mark, self.trained, self.model = self.model.unverified, new, copy_model(new)
            if self.day_scale is not None:  # a carried day: its mark kept until spread
                hold_day(self.model, *cal, mark)
            self._scale(self.model.interval_scale)
            self.version += 1

    def _publish_gated(self) -> tuple[bool, float]:
        """Publish the update unless the gate withholds it (the held-out error grew beyond the
        tolerance; the last published model stays). Withheld?, and held-out error (mm)."""
        before = holdout_mm(self.model, self._cal_x, self._cal_y)
        last, scales = copy_model(self.model), (self.day_scale, self.aci_log_scale)
        self._publish()
        after = holdout_mm(self.model, self._cal_x, self._cal_y)
        if withhold(before, after, len(self._cal_x), self.cfg.quarantine):
            self.model, self.n_withheld = last, self.n_withheld + 1
            self.day_scale, self.aci_log_scale = scales
            return True, before
        self.version += 1
        return False, after

    def remember(self, X: np.ndarray, Y: np.ndarray) -> None:
        """Fill the memory from points the model was trained on (a batch-trained model that goes
        on learning): the ``memory`` worst predicted, as max-error replay keeps them."""
        X, Y = checked_batch(X, Y, self.model.spec.n_features)
        errors = np.linalg.norm(
            (self.trained.predict(X).gamma - Y) / self.trained.label_std, axis=1
        )
        keep = np.sort(np.argsort(errors)[::-1][: self.cfg.memory])
        self._mem_x, self._mem_y = X[keep], Y[keep]
        self.n_seen = len(X)

    def carry(self, X: np.ndarray, Y: np.ndarray) -> float:
        """Start a new day or cell from its first points ``X, Y``: its frames fitted again, the
        carried network's gain on them, returned (:func:`learner.continual_day.carry`)."""
        return continual_day.carry(self, X, Y)

    def rebase(self, base: PhysicsBase, keep: np.ndarray | None = None) -> None:
        """Put both models on a new physics base, the memory's labels moved with it
        (:func:`learner.continual_day.rebase`)."""
        continual_day.rebase(self, base, keep)

    def _adapt_intervals(self, X: np.ndarray, Y: np.ndarray) -> float:
        """Adaptive conformal inference on the interval scale, point by point in stream order
        (:mod:`learner.conformal`): misses widen the intervals, points inside narrow them.
        Returns the published model's 90 % coverage of the points before it learned them."""
        c, ev = self.cfg, self.model.predict(X)
        if c.aci_rate:
            lo, hi = ev.interval(c.aci_level)
            excess = np.abs(2.0 * Y - lo - hi) / (hi - lo)
            self.aci_log_scale = adapt_log_scale(
                self.aci_log_scale, excess, c.aci_rate, c.aci_level
            )
        return interval_coverage(ev, Y, 0.90)

    def _publish(self) -> None:
        """Move the published weights towards the trained ones by ``average`` (the envelope
        follows); calibrate on the held-out set (the trained model's scale while it is small);
        after a :meth:`carry`, re-weigh the network on the day's held-out points first, or keep
        the scale the model came with while they are fewer than :data:`MIN_DAY_POINTS`."""
        published, trained = self.model.net.state_dict(), self.trained.net.state_dict()
        with torch.no_grad():
            for name, weights in published.items():
                weights.lerp_(trained[name], self.cfg.average)
        self.model.envelope = self.trained.envelope
        carried, cal = self.day_scale is not None, (self._cal_x, self._cal_y)
        if carried and len(self._cal_x) < MIN_DAY_POINTS:  # a young day: the scale it came with
            self.model.interval_scale = self.day_scale.copy()
        elif len(self._cal_x) >= MIN_CALIBRATION:
            if carried:
                self.trained.residual_gain = self.model.weigh_residual(*cal)
                hold_day(self.model, *cal, self.model.unverified)
            self.model.calibrate(*cal)
        else:
            self.model.interval_scale = self.trained.interval_scale.copy()
        self._scale(self.model.interval_scale)

    def _scale(self, scale: np.ndarray) -> None:
        """Publish the calibrated interval ``scale`` times the ACI scale; on a carried day ACI
        takes up its change from :attr:`day_scale`, so that the published scale stays unless
        ``scale`` is wider (:func:`learner.conformal.take_up`)."""
        if self.day_scale is not None:
            self.aci_log_scale = take_up(self.aci_log_scale, self.day_scale, scale)
            self.day_scale = np.asarray(scale, dtype=float).copy()
        self.model.interval_scale = scale * np.exp(self.aci_log_scale)

    def _metrics(
        self,
        n_new: int,
        kept: int,
        report: TrainReport | None,
        dt: float,
        err: np.ndarray | None = None,
    ) -> UpdateMetrics:
        """This step's :class:`UpdateMetrics` (``err``: the new points' errors before it, m)."""
        counts = (self.version, self.n_seen, n_new, len(self._mem_x), kept)
        train_mm = memory_mm(self.trained, self._mem_x, self._mem_y)
        return UpdateMetrics.of(*counts, report, dt, err, train_mm)

    def state_dict(self) -> dict:
        """Everything a restart needs (:func:`learner.continual_state.learner_state`)."""
        return learner_state(self)

    def load_state(self, state: dict) -> None:
        """Continue from a :meth:`state_dict` (the models are replaced by the stored ones)."""
        restore_learner(self, state)


def load_learner(model_path: str | Path, cfg: ContinualConfig) -> ContinualLearner:
    """A learner that goes on from a model file: from its state beside it (memory included)
    when there is one, else from the snapshot alone with an empty memory."""
    model = load_snapshot(model_path)
    learner = ContinualLearner(model, cfg)
    if state_path(model_path).is_file():
        learner.load_state(state_from_bytes(state_path(model_path).read_bytes()))
    return learner
