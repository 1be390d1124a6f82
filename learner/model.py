"""``ErrorModel``: the pose-error estimator (network, fixed scalers, configs, feature names).

The model is a physics base plus a learned residual (:mod:`learner.base`): its prediction is
the base's pose error against the nominal model plus what the network predicts of the rest, so
labels stay DESIGN.md's (the error against the nominal) whatever the base. Inputs are encoded
from the raw features by :mod:`learner.encoding` on scales fixed by the robot description
(:class:`~learner.features.FeatureSpec`); the residual labels are standardised per component
by a mean and std fixed on the model's first ``fit`` and never changed afterwards.
Validation MSE is in these scaled label units (1.0 = the spread of the first training labels),
of the mean the model serves (:func:`~learner.evidential.served_mean`).

>>> from kinematics.description import load_description
>>> from learner.features import feature_spec
>>> spec = feature_spec(load_description("ur10"), 0, False)
>>> m = ErrorModel.create(spec, ModelConfig(hidden_layers=1, neurons=8), TrainConfig(), seed=0)
>>> m.predict(np.zeros((2, 6))).gamma.shape
(2, 6)
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Protocol, runtime_checkable

import numpy as np
import torch
from scipy import optimize, stats

from kinematics.errors import DatasetError
from kinematics.model import RobotModel
from learner.base import PhysicsBase
from learner.config import ModelConfig, TrainConfig
from learner.encoding import input_encoder, n_inputs
from learner.ensemble import EvidentialEnsemble
from learner.envelope import Envelope, widen
from learner.evidential import Evidential, combine_members, served_mean
from learner.features import FeatureSpec, temperature_readings
from learner.training import Trainer, TrainReport, train_loop

N_LABELS = 6
#: Fewest held-out points the interval scale is calibrated on (fit, continual updates).
MIN_CALIBRATION = 5


@runtime_checkable
class ErrorModelProtocol(Protocol):
    """What every error model gives the learner, the stages and the snapshots (River's
    estimator protocol): its feature spec and seed, ``fit`` on raw SI features ``(N, F)`` and
    labels ``(N, 6)`` (m, rad), an NIG ``predict`` in label units and an unfitted ``clone``.
    Members pass ``tests/learner/test_error_model_conformance.py``."""

    spec: FeatureSpec
    seed: int
    robot: str

    @property
    def is_fitted(self) -> bool: ...

    def fit(self, X: np.ndarray, Y: np.ndarray) -> TrainReport: ...

    def predict(self, X: np.ndarray) -> Evidential: ...

    def clone(self) -> ErrorModelProtocol: ...


class ErrorModel:
    """Predicts the pose error ``(N, 6)`` with NIG uncertainty from raw SI features ``(N, F)``."""

    def __init__(
        self,
        *,
        spec: FeatureSpec,
        model_cfg: ModelConfig,
        train_cfg: TrainConfig,
        seed: int,
        robot: str = "",
        label_mean: np.ndarray | None = None,
        label_std: np.ndarray | None = None,
        interval_scale: np.ndarray | None = None,
        base: PhysicsBase | None = None,
        residual_gain: float = 1.0,
        envelope: Envelope | None = None,
        unverified: str = "",
        drift_scale: np.ndarray | None = None,
    ) -> None:
        self.spec = spec
        self.base = base
        self.model_cfg = model_cfg
        self.train_cfg = train_cfg
        self.seed = seed
        self.robot = robot
        self.label_mean = None if label_mean is None else np.asarray(label_mean, dtype=float)
        self.label_std = None if label_std is None else np.asarray(label_std, dtype=float)
        self.interval_scale = (
            np.ones(N_LABELS) if interval_scale is None else np.asarray(interval_scale, dtype=float)
        )
        self.residual_gain = float(residual_gain)
        self.envelope = envelope  # the joint angles and temperatures trained on
        #: Why its intervals are not to be stood behind yet ("" when they are): a carry that
        #: took the frames as moved, until the day's own held-out points have checked them
        #: (:meth:`learner.continual.ContinualLearner.carry`). Compensation flags it.
        self.unverified = unverified
        #: How many times wider, per component, its intervals must be on a later day than its
        #: own scale makes them, as its training days' last hours showed (ones: not measured;
        #: :func:`learner.carry.drift_scale`). A carry into a new day starts with them so wide.
        self.drift_scale = np.ones(N_LABELS) if drift_scale is None else np.array(drift_scale)
        self.net = EvidentialEnsemble(
            n_inputs=n_inputs(spec, model_cfg.encoding),
            hidden_layers=model_cfg.hidden_layers,
            neurons=model_cfg.neurons,
            activation=model_cfg.activation,
            dropout=model_cfg.dropout,
            n_heads=N_LABELS * model_cfg.members,
            seed=seed,
        )
        self._encode = input_encoder(spec, model_cfg.encoding)
        self._nominal: RobotModel | None = None
        self.skipped_steps = 0
        self.metrics: dict[str, float] = {}

    @classmethod
    def create(
        cls,
        spec: FeatureSpec,
        model_cfg: ModelConfig,
        train_cfg: TrainConfig,
        seed: int,
        robot: str = "",
        base: PhysicsBase | None = None,
    ) -> ErrorModel:
        """A fresh, untrained model (weights drawn from ``seed``) on ``base`` (none: nominal)."""
        return cls(
            spec=spec, model_cfg=model_cfg, train_cfg=train_cfg, seed=seed, robot=robot, base=base
        )

    def clone(self) -> ErrorModel:
        """A fresh, untrained model with this one's spec, configs, seed, robot and base (its
        hyper-parameters, as River's ``clone``): trained alike it predicts alike."""
        return ErrorModel.create(
            self.spec, self.model_cfg, self.train_cfg, self.seed, self.robot, self.base
        )

    @property
    def feature_names(self) -> tuple[str, ...]:
        return self.spec.names

    @property
    def n_weights(self) -> int:
        return self.net.n_weights

    @property
    def is_fitted(self) -> bool:
        return self.label_mean is not None

    @property
    def base_kind(self) -> str:
        return "nominal" if self.base is None else self.base.kind

    def base_error(self, X: np.ndarray) -> np.ndarray:
        """What the physics base predicts of the pose error ``(N, 6)`` (m, rad) at ``X``."""
        if self.base is None or self.base.kind == "nominal":
            return np.zeros((np.shape(X)[0], N_LABELS))
        return self.base.error(self.spec, X, self._nominal_model())

    def _nominal_model(self) -> RobotModel:
        if self._nominal is None:
            self._nominal = RobotModel(self.spec.description)
        return self._nominal

    # -- scaling -------------------------------------------------------------------------------

    def scale_x(self, X: np.ndarray) -> torch.Tensor:
        """Raw features -> encoded float32 network inputs (DatasetError on a wrong shape)."""
        return torch.as_tensor(self._encode(X), dtype=torch.float32)

    def scale_y(self, Y: np.ndarray) -> torch.Tensor:
        """Residual labels (m, rad; the label less :meth:`base_error`) -> standardised float32."""
        Y = _check_labels(Y)
        return torch.as_tensor((Y - self.label_mean) / self.label_std, dtype=torch.float32)

    def _ensure_label_scaler(self, Y: np.ndarray) -> None:
        if self.label_mean is None:
            Y = _check_labels(Y)
            self.label_mean = Y.mean(axis=0)
            std = Y.std(axis=0)
            self.label_std = np.where(std > 1e-12, std, 1.0)

    # -- prediction ----------------------------------------------------------------------------

    def predict_scaled(self, Xs: torch.Tensor) -> tuple[torch.Tensor, ...]:
        """NIG outputs ``(N, 6)`` in scaled label units for scaled features, the members
        combined (no grad, eval mode)."""
        if self.net.training:  # eval() walks every submodule: a tenth of a one-pose call
            self.net.eval()
        with torch.inference_mode():
            return combine_members(*self.net(Xs), self.model_cfg.members)

    def predict(self, X: np.ndarray) -> Evidential:
        """NIG prediction in label units (m, rad) for raw SI features ``(N, F)``: the base's
        error plus the network's residual, weighed against its prior (the training residuals'
        spread) by its epistemic variance and scaled by :attr:`residual_gain` (1 unless a new
        day's points said how far a carried network holds, :meth:`weigh_residual`). Where the
        network extrapolates, the prediction falls back to the base."""
        gamma, nu, alpha, beta = (t.double().numpy() for t in self.predict_scaled(self.scale_x(X)))
        mean = np.zeros(N_LABELS) if self.label_mean is None else self.label_mean
        std = np.ones(N_LABELS) if self.label_std is None else self.label_std
        if self.label_std is not None:  # the residual's prior N(mean, std²) meets the network's
            gamma = served_mean(gamma, nu, alpha, beta)
        residual = mean + std * gamma
        base = self.base_error(X)
        beta = (beta * std**2 + self._frame_beta(X, base, nu, alpha)) * self.interval_scale**2
        gamma = self.residual_gain * residual + base
        return Evidential(gamma=gamma, nu=nu, alpha=alpha, beta=beta)

    def _frame_beta(
        self, X: np.ndarray, base: np.ndarray, nu: np.ndarray, alpha: np.ndarray
    ) -> np.ndarray:
        """What the base frames' uncertainty (:meth:`PhysicsBase.frame_variance` around the base's
        error ``base``, after a new day's re-identification) adds to ``beta``: its variance added
        to the Student-t predictive variance ``beta (1 + nu) / (nu (alpha - 1))`` (label units²)."""
        if self.base is None or self.base.frame_sigma is None:
            return np.zeros_like(nu)
        variance = self.base.frame_variance(self.spec, X, self._nominal_model(), base)
        return variance * nu * (alpha - 1.0) / (1.0 + nu)

    def residual(self, X: np.ndarray) -> np.ndarray:
        """What the network adds to the base at ``X`` ``(N, 6)`` (m, rad), as :meth:`predict`
        weighs it: a new day's frames are fitted to the labels less this."""
        if self.label_mean is None:
            return np.zeros((np.shape(X)[0], N_LABELS))
        return self.predict(X).gamma - self.base_error(X)

    def weigh_residual(self, X: np.ndarray, Y: np.ndarray) -> float:
        """Fit :attr:`residual_gain` in [0, 1] to points the network never trained on (least
        squares of the labels less the base, standardised units); returns it. A network carried
        to another cell learned its residual elsewhere: UR10 A's network on B's poses has gain
        0-0.1; gain 1 cost 0.07-0.45 mm after 100 points (BENCHMARKS.md)."""
        Y = _check_labels(Y)
        self.residual_gain = 1.0
        if not self.is_fitted:
            return self.residual_gain
        residual = self.residual(X) / self.label_std
        target = (Y - self.base_error(X)) / self.label_std
        power = float(np.sum(residual**2))
        gain = float(np.sum(residual * target)) / power if power > 0 else 1.0
        self.residual_gain = float(np.clip(gain, 0.0, 1.0))
        return self.residual_gain

    def calibrate(self, X: np.ndarray, Y: np.ndarray) -> np.ndarray:
        """Fit the per-component factor on the Student-t scale that minimises the predictive
        NLL of held-out ``(X, Y)`` (``beta`` is multiplied by its square); returns it. Networks
        trained on few points are over-confident on new ones; this one scalar per component,
        fitted on data the weights never saw, makes the intervals honest."""
        Y = _check_labels(Y)
        self.interval_scale = np.ones(N_LABELS)
        ev = self.predict(X)
        z = (Y - ev.gamma) / ev.scale()
        df = 2.0 * ev.alpha
        scale = np.ones(N_LABELS)
        for c in range(N_LABELS):

            def nll(log_s: float, c: int = c) -> float:
                return float(np.sum(-stats.t.logpdf(z[:, c] * np.exp(-log_s), df[:, c]) + log_s))

            scale[c] = np.exp(optimize.minimize_scalar(nll, bounds=(-7.0, 7.0), method="bounded").x)
        self.interval_scale = scale
        return scale

    # -- training ------------------------------------------------------------------------------

    def validation_rows(self, n: int) -> np.ndarray:
        """The rows of ``n`` training points that :meth:`fit` (no ``X_val``, the config's
        fraction) holds out for validation: the same seeded draw (none below 10 points)."""
        gen = torch.Generator().manual_seed(self.train_cfg.seed + self.seed)
        return _validation_split(gen, n, self.train_cfg.val_fraction)[1]

    def fit(
        self,
        X: np.ndarray,
        Y: np.ndarray,
        X_val: np.ndarray | None = None,
        Y_val: np.ndarray | None = None,
        on_epoch: Callable[[int, float], None] | None = None,
        *,
        max_epochs: int | None = None,
        val_fraction: float | None = None,
        lr: float | None = None,
        anneal: bool = False,
        trainer: Trainer | None = None,
    ) -> TrainReport:
        """Train (warm-started from the current weights) with Adam and the evidential loss;
        the training points' joint angles and temperatures widen :attr:`envelope`.

        Without ``X_val`` a ``val_fraction`` of ``X`` is held out for the lr schedule and early
        stopping; the best weights by validation MSE are kept and the interval scale is
        calibrated on the validation set (:meth:`calibrate`). ``on_epoch(epoch, val_mse)`` runs
        after every epoch (val MSE in scaled label units, train loss when no validation) and may
        raise to stop training (e.g. ``optuna.TrialPruned``); the exception propagates.
        ``max_epochs``, ``val_fraction`` and ``lr`` override the train config for this call;
        ``anneal`` lets the rate fall to 0 over ``max_epochs`` instead of cutting it on
        plateaus (a continual update's fixed budget); ``trainer`` runs the loop
        (:func:`train_loop` here, or e.g. a :class:`~learner.train_process.TrainProcess`).
        """
        cfg = self.train_cfg
        X = np.asarray(X, dtype=float)
        Y = _check_labels(Y)
        if X.shape[0] != Y.shape[0]:
            raise DatasetError(f"features and labels differ in rows: {X.shape[0]} vs {Y.shape[0]}")
        if X.shape[0] == 0:
            raise DatasetError("cannot fit on 0 points")
        gen = torch.Generator().manual_seed(cfg.seed + self.seed)
        frac = cfg.val_fraction if val_fraction is None else val_fraction
        if X_val is None:
            rest, held = _validation_split(gen, X.shape[0], frac)
            if len(held):
                X, Y, X_val, Y_val = X[rest], Y[rest], X[held], Y[held]
        R = Y - self.base_error(X)  # the network learns what the base leaves
        self.envelope = widen(
            self.envelope, X[:, : self.spec.n_joints], temperature_readings(self.spec, X)
        )
        self._ensure_label_scaler(R)
        Xs, Ys = self.scale_x(X), self.scale_y(R)
        val = None
        if X_val is not None:
            val = (self.scale_x(X_val), self.scale_y(_check_labels(Y_val) - self.base_error(X_val)))
        epochs = max_epochs or cfg.max_epochs
        loop = trainer or train_loop
        report = loop(self, Xs, Ys, val, gen, epochs, lr or cfg.lr, on_epoch, anneal=anneal)
        if X_val is not None and len(X_val) >= MIN_CALIBRATION:
            self.calibrate(X_val, Y_val)
        return report


def _validation_split(
    gen: torch.Generator, n: int, fraction: float
) -> tuple[np.ndarray, np.ndarray]:
    """The rows of ``n`` training points that train and that validate, a ``fraction`` of them
    drawn from ``gen`` (none below 10 points or at fraction 0; ``gen`` then left as it was)."""
    if fraction <= 0 or n < 10:
        return np.arange(n), np.empty(0, dtype=int)
    order = torch.randperm(n, generator=gen).numpy()
    n_val = max(1, round(fraction * n))
    return order[n_val:], order[:n_val]


def _check_labels(Y: np.ndarray) -> np.ndarray:
    Y = np.asarray(Y, dtype=float)
    if Y.ndim != 2 or Y.shape[1] != N_LABELS:
        raise DatasetError(f"labels must have shape (N, {N_LABELS}), got {Y.shape}")
    if not np.all(np.isfinite(Y)):
        raise DatasetError(f"labels row {np.argwhere(~np.isfinite(Y))[0, 0]}: not finite")
    return Y
