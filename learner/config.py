"""Configurations of the learner: network shape, batch training and continual learning.

Frozen ``kw_only`` dataclasses validated on construction; the defaults were picked by
measurement on the simulated paper campaign and the real UR10 series (see BENCHMARKS.md,
"Learner" and "Real robots").

>>> ModelConfig(hidden_layers=2, neurons=64).activation
'gelu'
>>> ContinualConfig(strategy="lru")  # doctest: +ELLIPSIS
Traceback (most recent call last):
...
kinematics.errors.ConfigError: continual.strategy must be one of (...), got 'lru'
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

from kinematics.errors import ConfigError
from kinematics.outliers import GROSS_THRESHOLD

ACTIVATIONS = ("elu", "relu", "gelu")
STRATEGIES = ("max_error", "naive", "reservoir", "full")
ENCODINGS = ("kinematic", "minmax")
#: Physics bases the learner can identify itself (:mod:`learner.base`; a file is a path).
BASE_KINDS = ("nominal", "geometric", "auto", "gap")
#: The kinds a stream identifies from its first points; a gap model needs every training point
#: at once (from UR10 Series A's first 50 it is 1.1 mm off on the rest of the series, under the
#: calibration prior): pass ``robocal gap``'s file.
STREAM_BASE_KINDS = ("nominal", "geometric", "auto")
#: The one base that measured best on real data (BENCHMARKS.md, "Real UR10"): ``robocal hpo``'s
#: default and the benches' base.
DEFAULT_BASE = "geometric"
#: ``robocal train``'s default: the residual trained on the ``geometric`` and on the ``gap``
#: base, the gap one kept where its validation error is lower by a margin
#: (:func:`learner.workflow.best_on_validation`): on random arms whose effects it names it wins
#: by 1.1-5 x, on the real UR10 by 0-7 %.
SELECTED_BASE = "best"
#: Prior of a re-identified frame parameter (:func:`learner.carry.reidentify_frames`): a
#: Gaussian whose std moves the tool pose by this much (mm, RMS over the new points; rotations
#: on a 1 m lever), weighed against what a free fit of the frames leaves (``s_p``), so the
#: source's frames count as about ``(s_p / FRAME_PRIOR_MM)²`` points. A new day's first
#: points, often from one region, carry the robot's local error (0.3-0.5 mm on a UR10), which
#: a loose prior folds into frame rotations that tilt the far workspace: UR10 A -> B with a
#: geometric base, after 100 points, 0.53 mm at 0.03 against 0.67 mm at 0.3 (B -> A 0.55 /
#: 0.57 mm).
FRAME_PRIOR_MM = 0.03
#: The prior once the first points show that the tracker or tool moved
#: (:func:`learner.carry.carried_frames`): held at 0.03 mm, a tracker moved by 2 mm is 1.87 mm
#: off after 10 points and 0.25 mm after 100 in the simulated cell, at 0.3 mm 0.12 / 0.09 mm.
#: A base that explains the local error itself may take it from the start (A's gap model as
#: the base: UR10 A -> B 0.39 mm at 0.3 against 0.65 mm at 0.03). BENCHMARKS.md, "Frame prior
#: and base".
MOVED_FRAME_PRIOR_MM = 0.3
#: How many of a carried day's trained points its frames are fitted again on, each time they
#: double (:class:`learner.carry.CarriedDay`): a tracker moved by 2 mm, streamed days of six
#: random arms and the simulated cell ended 1-45 % closer than with the first points' frames
#: alone; 800 points hold a frame fit's information and keep each fit under a second.
DAY_FRAME_POINTS = 800


def _check(cond: bool, msg: str) -> None:
    if not cond:
        raise ConfigError(msg)


def _check_counts(cfg: object, section: str, names: tuple[str, ...]) -> None:
    """Each field ``names`` of ``cfg`` is an int >= 1 (else ``<section>.<name>`` ConfigError)."""
    for name in names:
        value = getattr(cfg, name)
        _check(
            isinstance(value, int) and value >= 1,
            f"{section}.{name} must be an int >= 1, got {value!r}",
        )


def is_model_file(base: str) -> bool:
    """Whether ``base`` names a model file (``robocal calibrate``/``robocal gap``), not a kind."""
    return str(base).endswith(".toml")


def _check_choice(
    section: str, name: str, value: object, choices: tuple[str, ...], why: str = ""
) -> None:
    """``value`` is one of ``choices`` (else ``<section>.<name>`` ConfigError, ``why`` after)."""
    why = f" ({why})" if why else ""
    _check(value in choices, f"{section}.{name} must be one of {choices}, got {value!r}{why}")


@dataclass(frozen=True, kw_only=True)
class ModelConfig:
    """Shape of each of the six per-component MLPs, how many independently initialised
    ``members`` each component has (their disagreement adds to the epistemic variance, see
    :func:`learner.evidential.combine_members`) and how raw features become their inputs
    (``encoding``, see :mod:`learner.encoding`). Three hidden layers, chosen on real data: on
    the UR10 series they cut the test error by a fifth against two (A 0.108 -> 0.084 mm, B
    0.266 -> 0.212 mm at 300 epochs; BENCHMARKS.md, "Three hidden layers")."""

    hidden_layers: int = 3
    neurons: int = 64
    activation: str = "gelu"
    dropout: float = 0.0
    members: int = 2
    encoding: str = "kinematic"

    def __post_init__(self) -> None:
        _check(
            isinstance(self.hidden_layers, int) and 1 <= self.hidden_layers <= 32,
            f"model.hidden_layers must be an int in [1, 32], got {self.hidden_layers!r}",
        )
        _check(
            isinstance(self.neurons, int) and 1 <= self.neurons <= 4096,
            f"model.neurons must be an int in [1, 4096], got {self.neurons!r}",
        )
        _check_choice("model", "activation", self.activation, ACTIVATIONS)
        _check(0.0 <= self.dropout < 1.0, f"model.dropout must be in [0, 1), got {self.dropout}")
        _check(
            isinstance(self.members, int) and 1 <= self.members <= 16,
            f"model.members must be an int in [1, 16], got {self.members!r}",
        )
        _check_choice("model", "encoding", self.encoding, ENCODINGS)


@dataclass(frozen=True, kw_only=True)
class TrainConfig:
    """Batch training: Adam, weight decay, lr × 0.75 after ``patience_lr`` epochs without
    validation improvement, early stopping after ``early_stop_patience``, best weights kept.
    The evidential loss can stall for up to 200 epochs before the mean fits again: at 80, 3 of
    24 seeds on 600 real UR10 points stopped there, 15-28 % worse (BENCHMARKS.md, "Early
    stopping's patience").
    ``lam`` weighs the evidence regulariser; ``nll_variance_power`` weighs each point's NLL by
    its predicted variance to that power (β-NLL, :mod:`learner.evidential`; 0: the NLL as
    DESIGN.md writes it). ``val_fraction`` is split off when no validation set is given (0
    trains all ``max_epochs`` on everything and keeps the last weights). ``drift_fraction``:
    the last part of the training points in time that batch training holds out once more to
    measure how much wider the intervals must be on a later day (``learner.carry.drift_scale``;
    0: not measured)."""

    batch_size: int = 64
    lr: float = 3e-3
    weight_decay: float = 1e-5
    max_epochs: int = 1500
    patience_lr: int = 30
    early_stop_patience: int = 200
    lam: float = 0.01
    nll_variance_power: float = 0.25
    val_fraction: float = 0.1
    drift_fraction: float = 0.1
    seed: int = 0

    def __post_init__(self) -> None:
        _check(
            isinstance(self.batch_size, int) and self.batch_size >= 1,
            f"train.batch_size must be an int >= 1, got {self.batch_size!r}",
        )
        _check(0.0 < self.lr < 1.0, f"train.lr must be in (0, 1), got {self.lr}")
        _check(
            0.0 <= self.weight_decay < 1.0,
            f"train.weight_decay must be in [0, 1), got {self.weight_decay}",
        )
        _check_counts(self, "train", ("max_epochs", "patience_lr", "early_stop_patience"))
        _check(self.lam >= 0.0, f"train.lam must be >= 0, got {self.lam}")
        _check(
            0.0 <= self.nll_variance_power <= 1.0,
            f"train.nll_variance_power must be in [0, 1], got {self.nll_variance_power}",
        )
        _check(
            0.0 <= self.val_fraction < 1.0,
            f"train.val_fraction must be in [0, 1), got {self.val_fraction}",
        )
        _check(
            0.0 <= self.drift_fraction < 1.0,
            f"train.drift_fraction must be in [0, 1), got {self.drift_fraction}",
        )
        _check(isinstance(self.seed, int), f"train.seed must be an int, got {self.seed!r}")


@dataclass(frozen=True, kw_only=True)
class QuarantineConfig:
    """Defence against poisoned measurements (:mod:`learner.quarantine`). A new point is
    quarantined — never trained on, held out or kept in memory — when its residual against the
    published model lies more than ``interval_threshold`` predictive (Student-t) scales from the
    prediction in some component, more than ``threshold`` robust units (normal-scaled MADs,
    norm over the six components) from its neighbours' residuals (the ``history`` latest
    accepted points and its own batch), AND its label more than ``label_threshold`` such units
    from their labels. Before the first model the label alone is judged, against
    ``warmup_threshold``. ``release_after`` consecutive quarantined points are taken as a
    lasting change of the cell, not a fault: the quarantine lets the shift through and follows
    it. An update whose published model's median held-out position error exceeds the last
    published one's by more than ``publish_tolerance`` (relative) is withheld (``inf`` turns
    the gate off); the gate waits for ``gate_min_points`` held-out points. ``enabled`` false
    turns the quarantine off (the gate stays). Thresholds from the clean and poisoned streams of
    BENCHMARKS.md, "No poisoning"."""

    enabled: bool = True
    threshold: float = 25.0
    interval_threshold: float = 4.0
    label_threshold: float = 10.0
    warmup_threshold: float = GROSS_THRESHOLD
    history: int = 500
    release_after: int = 100
    publish_tolerance: float = 0.1
    gate_min_points: int = 20

    def __post_init__(self) -> None:
        _check(
            isinstance(self.enabled, bool),
            f"quarantine.enabled must be a bool, got {self.enabled!r}",
        )
        for key in ("threshold", "interval_threshold", "label_threshold", "warmup_threshold"):
            value = getattr(self, key)
            _check(
                isinstance(value, int | float) and value > 0,
                f"quarantine.{key} must be > 0, got {value!r}",
            )
        for key in ("history", "release_after", "gate_min_points"):
            value = getattr(self, key)
            _check(
                isinstance(value, int) and value >= 1,
                f"quarantine.{key} must be an int >= 1, got {value!r}",
            )
        _check(
            isinstance(self.publish_tolerance, int | float)
            and not math.isnan(self.publish_tolerance)
            and self.publish_tolerance >= 0,
            "quarantine.publish_tolerance must be >= 0 (inf: no gate), "
            f"got {self.publish_tolerance!r}",
        )


@dataclass(frozen=True, kw_only=True)
class ContinualConfig:
    """Continual learning: memory ``N_m``, batch ``n_B``, ``init`` points for the first model,
    the replay ``strategy``, the epochs and learning rate of the warm-started training after
    each batch (fine-tuning, below the first fit's rate: a fresh Adam at the full rate moves
    every weight and forgets what the memory no longer holds), and the ``holdout`` share of
    each batch kept out of training in a first-in-first-out set of ``calibration_size`` points
    that picks the epoch each update keeps and on which the intervals are calibrated. An
    update's rate falls from ``update_lr`` to 0 along a half cosine over its epochs: the
    annealed weights are precise where a constant rate left them jittering. The published
    model is an exponential moving average of the trained weights over updates; ``average`` is
    the latest update's share (1 publishes the trained weights as they are). 0.7 with the
    annealed updates (0.4 under the constant rate): the paper campaign at N_m 2,000 +8.6 % ->
    +4.4 % of batch over six seeds, four random arms streamed 10 % closer, UR10 A 6 % closer;
    UR10 B in recorded order 4 % and N_m 500 16 % further (BENCHMARKS.md, "Continual updates
    annealed").
    An update trains ``epochs_per_update`` epochs over up to ``update_points`` memory points
    and proportionally fewer over more (:meth:`update_epochs`), so a larger memory costs
    little update time. ``memory`` 4,000: a real line streams its program in order, sweeping
    the workspace, and UR10 Series A (10,720 points) streamed so ended at 0.150 mm against
    0.213 mm at 2,000 (its batch model 0.081 mm; 0.115 mm at 4,000 with today's network and
    annealed updates); the paper campaign is the same at either (0.0252 / 0.0250 mm), random arms'
    6,000-point streams 0.093 against 0.095 mm (BENCHMARKS.md).
    ``calibration_size`` 1,000: a FIFO of 200 held only the front of a long stream, and its
    intervals covered 82-89 % of those arms' test points (now 90-91 %).
    ``base`` is the physics base the first model is identified on from the ``init`` points
    (:mod:`learner.base`; a model that has one keeps it; :mod:`learner.continual_base` says
    when it is identified again); ``auto`` takes the nominal when they are too few to identify
    it. A model file (``.toml``, against the stream's tracker) is the base as it is; one that
    leaves effects out is fitted to the stream as an identified base is
    (:func:`learner.base.refit_base`).
    ``frame_prior_mm`` is how far a carried base's frames may move on a new day's first
    points, ``moved_frame_prior_mm`` how far when those points show that the tracker or tool
    moved (:meth:`ContinualLearner.carry`, :func:`learner.carry.carried_frames`); the day's
    frames are fitted again each time its trained points double, up to ``day_frame_points``
    of them (0: the first points' frames stay). ``new_setup``: the tracker was set up anew
    for the carried day, so its frame is fitted freely on the day's points, the tool alone
    held (:class:`learner.carry.FramePriors`): its ``T_W_0`` is the nominal model's fit to its
    first points, and held near that UR10 B's model was 1.73 mm off A after A's first 10.
    ``reference_program``: the carried day's first ``init`` points are a reference program
    spread over the workspace (``robocal data reference-poses``), so the base's geometry is
    fitted again on them too (:func:`learner.carry_base.carried_base`) and its folds check
    the day's intervals (:func:`learner.carry_base.checking_labels`) and whether the effects
    the model's base brings, or the joint compliance it tries where the base has none
    (:func:`learner.carry_base.with_compliance`), hold on the day
    (:func:`learner.carry_base.keeps_effects`).
    ``aci_rate`` is the step of the adaptive conformal interval scale per new point outside
    (or inside) the ``aci_level`` interval, in log units (0 turns it off; it never narrows
    the intervals below the held-out calibration, :mod:`learner.conformal`).
    ``refresh_growth``: each time the points given grow by this factor a fresh network is
    trained on the memory and kept where it predicts the held-out set better
    (:mod:`learner.refresh`; 0, the default: never). At 2, UR10 Series B in recorded order
    0.289 -> 0.191 mm (three seeds; its memory holds every point), four random arms 0.0870 ->
    0.0844 mm, but UR10 A 0.115 -> 0.120 mm (seed 0) and the paper campaign at N_m 2,000
    0.0244 -> 0.0255 mm (seeds 0-8), whose memories drop points the warm network still knows
    (BENCHMARKS.md, "A fresh network on every stream, measured again").
    ``day_refresh_growth`` is the same on a carried day, counted on the day's own points (on
    by default: a stream from scratch never runs it; UR10 A's model carried through all of
    Series B 0.362 -> 0.281 mm, six random arms past a moved tracker 8.5 % closer, B through A
    0.108 -> 0.112 mm: "A fresh network on a carried day"). ``quarantine`` keeps poisoned
    points out and withholds updates that worsen the held-out error (a table
    ``[learner.continual.quarantine]`` in TOML)."""

    memory: int = 4000
    batch: int = 100
    init: int = 50
    strategy: str = "max_error"
    epochs_per_update: int = 60
    update_points: int = 2000
    init_epochs: int = 300
    update_lr: float = 1e-3
    holdout: float = 0.1
    calibration_size: int = 1000
    average: float = 0.7
    base: str = "auto"
    aci_rate: float = 0.05
    aci_level: float = 0.9
    frame_prior_mm: float = FRAME_PRIOR_MM
    moved_frame_prior_mm: float = MOVED_FRAME_PRIOR_MM
    day_frame_points: int = DAY_FRAME_POINTS
    new_setup: bool = False
    reference_program: bool = False
    refresh_growth: float = 0.0
    day_refresh_growth: float = 2.0
    seed: int = 0
    quarantine: QuarantineConfig = field(default_factory=QuarantineConfig)

    def __post_init__(self) -> None:
        if isinstance(self.quarantine, dict):  # a TOML table
            try:
                object.__setattr__(self, "quarantine", QuarantineConfig(**self.quarantine))
            except TypeError as exc:
                raise ConfigError(f"continual.quarantine: {exc}") from None
        _check(
            isinstance(self.quarantine, QuarantineConfig),
            f"continual.quarantine must be a table, got {type(self.quarantine).__name__}",
        )
        counts = (
            "memory",
            "batch",
            "init",
            "epochs_per_update",
            "update_points",
            "init_epochs",
            "calibration_size",
        )
        _check_counts(self, "continual", counts)
        _check_choice("continual", "strategy", self.strategy, STRATEGIES)
        _check(
            0.0 < self.update_lr < 1.0,
            f"continual.update_lr must be in (0, 1), got {self.update_lr}",
        )
        _check(
            0.0 <= self.holdout < 1.0, f"continual.holdout must be in [0, 1), got {self.holdout}"
        )
        _check(
            0.0 < self.average <= 1.0, f"continual.average must be in (0, 1], got {self.average}"
        )
        if not is_model_file(self.base):
            _check_choice(
                "continual",
                "base",
                self.base,
                STREAM_BASE_KINDS,
                "or a model file (.toml); a gap model needs every training point at once: "
                "pass `robocal gap`'s model file",
            )
        _check(
            0.0 <= self.aci_rate <= 1.0,
            f"continual.aci_rate must be in [0, 1], got {self.aci_rate}",
        )
        for name in ("new_setup", "reference_program"):
            value = getattr(self, name)
            _check(
                isinstance(value, bool), f"continual.{name} must be true or false, got {value!r}"
            )
        _check(
            0.0 < self.aci_level < 1.0,
            f"continual.aci_level must be in (0, 1), got {self.aci_level}",
        )
        for name in ("frame_prior_mm", "moved_frame_prior_mm"):
            value = getattr(self, name)
            _check(value > 0.0, f"continual.{name} must be > 0, got {value}")
        _check(
            isinstance(self.day_frame_points, int) and self.day_frame_points >= 0,
            f"continual.day_frame_points must be an int >= 0, got {self.day_frame_points!r}",
        )
        for name in ("refresh_growth", "day_refresh_growth"):
            value = getattr(self, name)
            _check(
                value == 0 or value > 1, f"continual.{name} must be 0 (never) or > 1, got {value}"
            )
        _check(isinstance(self.seed, int), f"continual.seed must be an int, got {self.seed!r}")

    def update_epochs(self, n_memory: int) -> int:
        """The epochs of an update over ``n_memory`` points: ``epochs_per_update``, fewer over a
        memory above ``update_points`` so that an update trains about as long whatever the memory.

        >>> ContinualConfig().update_epochs(1500), ContinualConfig().update_epochs(4000)
        (60, 30)
        """
        share = min(1.0, self.update_points / max(n_memory, 1))
        return max(1, round(self.epochs_per_update * share))
