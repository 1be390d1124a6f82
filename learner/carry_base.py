"""The base a carried day starts on: its frames from the day's first points and, where the line
says those points are a reference program spread over the workspace, its geometry as well.

A reference program (``robocal data reference-poses``) identifies the whole geometry, so the day's
own geometry is fitted under calibration's prior about the carried one, beside the frames: the arm
changes from day to day, not only its tracker. UR10, a tracker set up anew, after 100 reference
poses from the new series' first 1,000 training points: B→A 0.538 -> 0.440 mm, A→B 0.539 -> 0.448 mm
(BENCHMARKS.md, "A new set-up that starts with a reference program"). On a day's first points in
recorded order the same fit folds their region's error into the geometry (A→B 0.599 -> 0.644 mm): it
is a statement the line makes, never inferred, and it needs points that identify the geometry
(:data:`~learner.base.AUTO_MAX_CONDITION`). Spread over the workspace, the program also checks
the day's intervals: each pose as the base fitted without its fold misses it
(:func:`checking_labels`), and whether the effects a source's ``robocal gap`` base brings hold on
the day (:func:`keeps_effects`): UR10 A's, identified on its whole workspace, carry to B (A→B
0.416 mm after 100 poses, against 0.448 mm from a geometric source); B's, fitted on its corner,
miss A by 0.611 mm, and the folds drop them (0.443 mm). A base that brings no joint compliance
has one tried beside the geometry (:func:`with_compliance`), kept only where the folds show it
misses less: A→B from a geometric source 0.451 -> 0.407 mm after 100 poses, a random arm whose
joints twist 0.109 -> 0.066 mm at the end of its day, the other arms unchanged (BENCHMARKS.md,
"Joint compliance tried by a reference program"). The program judges the day's start;
the day's held-out points weigh the effects it dropped again as its frames are refitted
(:func:`day_frames`): a random arm whose source saw one corner got its gear terms back at 270
points and ended its day at 0.078 mm, not 0.320 mm.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, replace

import numpy as np
from scipy.stats import ttest_rel

from kinematics.calibration import CalibrationConfig, prior_std
from kinematics.effects.joint_compliance import JointCompliance, actuator_torque
from kinematics.errors import IdentifiabilityError
from kinematics.gap.model_file import EffectEntry
from kinematics.model import RobotModel
from learner.base import AUTO_MAX_CONDITION, PhysicsBase, effect_conditions, refit_base
from learner.carry import (
    MIN_DAY_POINTS,
    CarriedDay,
    FramePriors,
    carried_frames,
    reidentify_frames,
)
from learner.config import ContinualConfig
from learner.features import FeatureSpec

#: One-sided significance at which a reference program drops the carried base's effects: their
#: folds must miss by more than geometry alone's (paired t test over the poses), else the physics
#: the source identified stays. UR10, source models on their ``robocal gap`` files, 100 poses:
#: A's effects on B t = -1.7 / 0.0 / 0.9 (kept: 0.416 mm, geometry alone 0.460 mm), B's, fitted
#: on its corner, on A t = 3.6 / 2.4 / 2.7 (dropped: 0.443 mm, kept 0.611 mm).
DROP_EFFECTS_P = 0.05


@dataclass(frozen=True)
class DayPoints:
    """A carried day's first points: raw features ``X`` on ``spec``, labels ``Y`` (m, rad)
    and the carried network's ``residual`` (N, 6) there."""

    spec: FeatureSpec
    X: np.ndarray
    Y: np.ndarray
    residual: np.ndarray

    def rows(self, rows: np.ndarray) -> DayPoints:
        """The points at ``rows``."""
        return DayPoints(self.spec, self.X[rows], self.Y[rows], self.residual[rows])

    def gain(self, base: PhysicsBase) -> float:
        """The share in [0, 1] of the carried network's residual that explains what ``base``
        leaves of the positions (least squares, m): what
        :meth:`~learner.model.ErrorModel.weigh_residual` fits once the model stands on
        ``base``, needed here before it does, since the network learned its residual on
        another day."""
        error = base.error(self.spec, self.X, RobotModel(self.spec.description))
        left = np.asarray(self.Y, dtype=float)[:, :3] - error[:, :3]
        power = float(np.sum(self.residual[:, :3] ** 2))
        gain = float(np.sum(self.residual[:, :3] * left)) / power if power > 0 else 1.0
        return float(np.clip(gain, 0.0, 1.0))


@dataclass(frozen=True)
class DayBase:
    """The base a carried day starts on (:func:`carried_base`): whether its frames ``moved``,
    whether a reference program fitted its geometry again (``refitted``), which of the
    carried base's effects its folds showed do not hold on the day (``dropped``) and the base
    with them (``aside``: fitted on the same points, for the day's later points to weigh again)."""

    base: PhysicsBase
    moved: bool
    refitted: bool = False
    dropped: tuple[str, ...] = ()
    aside: PhysicsBase | None = None


def carried_base(
    base: PhysicsBase, day: DayPoints, cfg: ContinualConfig, keep_effects: bool | None = None
) -> DayBase:
    """``base`` for a new ``day`` from its first points: its frames
    (:func:`learner.carry.carried_frames`, whether they moved) and, with
    ``cfg.reference_program``, its geometry and effects fitted again on the points
    (:func:`day_fit`) where they identify it. Effects the base brings are kept, fitted again or
    as they came, unless the program's folds show that the day's geometry alone misses less
    (:func:`keeps_effects`; ``keep_effects`` decides instead). The note says which; effects
    the folds dropped are set aside (``DayBase.aside``) for the day's later points to weigh
    again (:func:`day_frames`). Where the points cannot identify the effects beside the
    geometry, the geometry stays as it came: fitted with the effects held, UR10 A→B from gap
    files went 0.427 -> 0.358 mm but B→A 0.442 -> 0.588 mm, B's corner-fitted gear terms passing
    the folds of a program from A's first hours (BENCHMARKS.md, "Measured, not kept")."""
    priors = FramePriors.of(cfg)
    framed, moved = carried_frames(base, day.spec, day.X, day.Y, day.residual, priors)
    if not cfg.reference_program:
        return DayBase(framed, moved)
    rigid, framed = framed, with_compliance(framed, day)
    why, checked = "", keep_effects is None and bool(framed.effects)
    if checked:
        keep_effects, why = keeps_effects(base, day, cfg)
    dropped = () if keep_effects is not False else tuple(e.name for e in framed.effects)
    added = framed is not rigid and not dropped
    tries = [replace(framed, effects=())] if dropped else [framed, rigid] if added else [framed]
    for start in tries:  # without the compliance added where it leaves the geometry unidentified
        try:
            fitted = day_fit(start, day)
            break
        except IdentifiabilityError as exc:
            error = exc
    else:
        note = f"{rigid.note}; reference program: geometry kept, {error}{why}"
        return DayBase(replace(rigid, note=note), moved)
    without = f" without the effects {', '.join(dropped)}" if dropped else ""
    note = (
        f"{framed.note}; reference program: geometry"
        f"{' and joint compliance' if added and start is framed else ''} fitted again on its "
        f"{len(day.X)} points{without}, condition number {fitted.condition:.3g}{why}"
    )
    aside = None  # where the folds dropped the effects, the base with them for the day to weigh
    if checked and dropped:
        aside = replace(carried_base(base, day, cfg, True).base, frame_sigma=None)
    return DayBase(replace(fitted, note=note, frame_sigma=None), moved, True, dropped, aside)


def with_compliance(base: PhysicsBase, day: DayPoints) -> PhysicsBase:
    """``base`` with a rigid ``joint_compliance`` as its one effect for a reference program to
    fit (each joint whose holding torque varies over the ``day``'s poses), where it brings no
    effects and the robot's link masses give torques; else ``base``. Every arm's joints twist
    under gravity; a geometric source does not know it, and its folds keep it only where it
    holds (:func:`keeps_effects`; a base with effects of its own is judged on those alone). The
    entry's std is the calibration prior's."""
    effect, cond = JointCompliance(), effect_conditions(day.spec, day.X)
    if base.effects or effect.needs(base.model, cond):
        return base
    torque = actuator_torque(base.model, cond)
    names = effect.parameter_names(base.description)
    prior = prior_std(base.model, effect, CalibrationConfig().prior_mm)
    varies = np.ptp(torque, axis=0) > 1e-6 * np.abs(torque).max(initial=0.0)
    std = {n: float(s) for n, s, v in zip(names, prior, varies, strict=True) if v}
    if not std:
        return base
    entry = EffectEntry(
        name=effect.name, options=effect.options(), parameters=dict.fromkeys(names, 0.0), std=std
    )
    return replace(base, effects=(*base.effects, entry))


def day_fit(framed: PhysicsBase, day: DayPoints) -> PhysicsBase:
    """``framed`` fitted again on a reference program's points
    (:func:`learner.base.refit_base`, identified at most as ill-conditioned as ``auto`` allows),
    to the labels less the share of the network's residual it leaves room for
    (:meth:`DayPoints.gain`)."""
    labels = np.asarray(day.Y, dtype=float) - day.gain(framed) * day.residual
    return refit_base(framed, day.spec, day.X, labels, max_condition=AUTO_MAX_CONDITION)


def held_misses(base: PhysicsBase, trained: DayPoints, held: DayPoints) -> np.ndarray:
    """How far (m) ``base`` and the network's residual, at the gain the ``trained`` points
    leave it (:meth:`DayPoints.gain`), miss each ``held`` point's position."""
    error = base.error(held.spec, held.X, RobotModel(held.spec.description))[:, :3]
    error += trained.gain(base) * held.residual[:, :3]
    return np.linalg.norm(error - held.Y[:, :3], axis=1)


def keeps_effects(
    base: PhysicsBase, day: DayPoints, cfg: ContinualConfig, folds: int = 5
) -> tuple[bool, str]:
    """Do the effects ``base`` brings hold on the day's reference program? Each pose's position
    error (m) where :func:`carried_base` on the other folds, with the effects and with the
    day's geometry alone, and the network's residual at the gain each leaves, miss it; the
    effects go only where geometry alone misses less at :data:`DROP_EFFECTS_P` (a source's
    effects fitted on a corner of its workspace). A compliance the program tries on a base
    that brings none (:func:`with_compliance`) stays only where it misses less at the same
    level: a new effect must earn its place. Returns the answer and a note of both."""
    n, misses, tried = len(day.X), {}, not base.effects  # tried: the compliance alone
    for keep in (True, False):
        miss = np.zeros(n)
        for fold in np.array_split(np.arange(n), min(folds, n)):
            rest = day.rows(np.setdiff1d(np.arange(n), fold))
            start = carried_base(base, rest, cfg, keep)
            if not (keep or start.refitted):
                return not tried, ""  # the day's geometry alone is not identified: no weighing
            miss[fold] = held_misses(start.base, rest, day.rows(fold))
        misses[keep] = miss
    p = ttest_rel(misses[True], misses[False], alternative="less" if tried else "greater").pvalue
    note = (
        f" (its folds: {misses[True].mean() * 1e3:.3f} mm with the "
        f"{'compliance tried' if tried else 'carried effects'}, "
        f"{misses[False].mean() * 1e3:.3f} mm without, p = {p:.2g})"
    )
    return bool(p < DROP_EFFECTS_P) == tried, note


def day_frames(
    day: CarriedDay, base: PhysicsBase, trained: DayPoints, held: DayPoints, cfg: ContinualConfig
) -> tuple[PhysicsBase, CarriedDay]:
    """A carried day's ``base`` with its frames fitted again on the day's ``trained`` points,
    from the frames it was carried from (:func:`learner.carry.carried_frames`), and the day on
    it. Where a reference program set effects aside (:attr:`CarriedDay.aside`), the base with
    them, its frames fitted the same way, takes over if the day's ``held`` out points (at least
    :data:`~learner.carry.MIN_DAY_POINTS`) show that it misses them less at
    :data:`DROP_EFFECTS_P`: the program judged the day's start, its later points judge
    the rest (a source fitted on a corner whose effects hold beyond it)."""
    priors = FramePriors.of(cfg)

    def refit(source: PhysicsBase) -> PhysicsBase:
        framed, _ = carried_frames(
            source, trained.spec, trained.X, trained.Y, trained.residual, priors
        )
        return framed

    fitted, day = refit(day.source(base)), replace(day, fitted=len(trained.X))
    if day.aside is None or len(held.X) < MIN_DAY_POINTS:
        return fitted, day
    other = refit(day.aside)
    now, then = held_misses(fitted, trained, held), held_misses(other, trained, held)
    p = ttest_rel(now, then, alternative="greater").pvalue
    if not p < DROP_EFFECTS_P:
        return fitted, day
    names = ", ".join(e.name for e in other.effects) or "none"
    note = (
        f"{other.note}; the day's {len(held.X)} held-out points took this base over at "
        f"{len(trained.X)} points (effects {names}: {then.mean() * 1e3:.3f} mm, "
        f"the other {now.mean() * 1e3:.3f} mm, p = {p:.2g})"
    )
    return replace(other, note=note), day.swapped(base)


def checking_labels(
    start: DayBase, base: PhysicsBase, day: DayPoints, cfg: ContinualConfig
) -> np.ndarray | None:
    """The labels on which a day carried from ``base`` to ``start`` checks its intervals, each
    of its first points as the same fit without its fold leaves it (:func:`held_out_labels`):
    a reference program's whole :func:`carried_base` where it fitted the geometry (spread over
    the workspace, its folds check the intervals everywhere), else a move's frames; None where
    the frames held."""
    if start.refitted:

        def fit_on(rows: np.ndarray) -> PhysicsBase:
            return carried_base(base, day.rows(rows), cfg, not start.dropped).base

    elif start.moved:
        priors = FramePriors.of(cfg)

        def fit_on(rows: np.ndarray) -> PhysicsBase:
            rest = day.rows(rows)
            return reidentify_frames(
                base,
                rest.spec,
                rest.X,
                rest.Y,
                residual=rest.residual,
                prior_m=priors.moved_m,
                tracker_free=priors.tracker_free,
            )

    else:
        return None
    return held_out_labels(start.base, day.spec, day.X, day.Y, fit_on)


def held_out_labels(
    fitted: PhysicsBase,
    spec: FeatureSpec,
    X: np.ndarray,
    Y: np.ndarray,
    fit_on: Callable[[np.ndarray], PhysicsBase],
    folds: int = 5,
) -> np.ndarray:
    """``Y`` moved so that ``fitted`` (a base fitted on all of ``X, Y``) leaves at each point
    what ``fit_on(rows)``, the same fit on the other folds' rows, leaves: calibrating
    intervals on them measures how far the fit misses points it was not fitted to, not how
    well it fits its own (on 10 points the second is far smaller). Fewer than 2 points: ``Y``
    as it is."""
    out = np.array(Y, dtype=float)
    if len(X) < 2:
        return out
    nominal = RobotModel(spec.description)
    out += fitted.error(spec, X, nominal)
    for fold in np.array_split(np.arange(len(X)), min(folds, len(X))):
        without = fit_on(np.setdiff1d(np.arange(len(X)), fold))
        out[fold] -= without.error(spec, X[fold], nominal)
    return out
