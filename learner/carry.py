"""A carried model's base on a new day: its frames re-identified from the day's first points.

When a model goes on in another day or cell (``robocal continual --from``, the daemon's
``start_from``), the tracker may have moved and the tool been re-mounted. The base's frames
(``T_0_B``, the tool) are fitted again to the first points, less what the network adds there
(:func:`reidentify_frames`), held near the old ones unless the points show a move
(:func:`carried_frames`); the carry calibrates its intervals on labels that frames fitted
without each point's fold leave (:func:`learner.carry_base.held_out_labels`). Where the frames
held, the day's first points still check the intervals the model came with
(:func:`scale_needed`): another day of the same cell can miss them by far. A carry starts the
day with its intervals as wide as its training days' own last hours showed a later day needs
(:func:`drift_scale`). The fitted frames keep their posterior spread (:func:`frame_sigma_points`,
``PhysicsBase.frame_sigma``): frames fixed by ten points of one corner are poorly known far
from it, and the intervals there say so. As the day's points keep coming
(:class:`CarriedDay`), its frames are fitted again on all of them.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, replace
from functools import partial

import numpy as np

from kinematics.calibration import (
    CalibrationConfig,
    GeometricFrames,
    apply_calibration,
    identifiable,
    identify,
)
from kinematics.description import RobotDescription
from kinematics.effects import Conditions, Effect, Perturbation
from kinematics.errors import IdentifiabilityError
from kinematics.identification.fitting import FitResult, fit_effects, jacobian, tool_motion_rms
from kinematics.model import RobotModel
from learner.base import AUTO_MAX_CONDITION, PhysicsBase, nominal_base
from learner.config import FRAME_PRIOR_MM, MOVED_FRAME_PRIOR_MM, ContinualConfig
from learner.features import FeatureSpec
from learner.model import ErrorModel
from learner.snapshot import copy_model


@dataclass(frozen=True)
class FramePriors:
    """How far a carried base's frames may move on a new day's first points (m, RMS tool
    motion of one standard deviation): ``held_m`` unless they show a move, ``moved_m`` then.
    ``tracker_free``: the tracker was set up anew for the day, so its frame (``T_0_B``) is
    fitted freely and only the tool is held. A new set-up's ``T_W_0`` comes from a fit of the
    nominal model to its first points, which folds their region's error in: held near it,
    UR10 B's model on A's first 10 points was 1.73 mm off (BENCHMARKS.md, "A new set-up's
    frames from its own first points")."""

    held_m: float = FRAME_PRIOR_MM * 1e-3
    moved_m: float = MOVED_FRAME_PRIOR_MM * 1e-3
    tracker_free: bool = False

    @classmethod
    def of(cls, cfg: ContinualConfig) -> FramePriors:
        """The priors a continual learner's settings name (``frame_prior_mm``,
        ``moved_frame_prior_mm``, ``new_setup``)."""
        return cls(cfg.frame_prior_mm * 1e-3, cfg.moved_frame_prior_mm * 1e-3, cfg.new_setup)


def reidentify_frames(
    base: PhysicsBase,
    spec: FeatureSpec,
    X: np.ndarray,
    Y: np.ndarray,
    offsets: bool = False,
    *,
    residual: np.ndarray | None = None,
    prior_m: float | None = FRAME_PRIOR_MM * 1e-3,
    tracker_free: bool = False,
) -> PhysicsBase:
    """The base with ``T_0_B``, its tool and (``offsets``) the joint offsets re-identified from
    ``X, Y`` (a new day's first points), the rest of its kinematics and its effects held: the
    tracker moved, the tool was re-mounted, an encoder was re-referenced. Only the parameters
    these points identify are fitted (pivoted QR, as in calibration), as a MAP estimate under a
    prior centred on the base's own frames (``prior_m``, m: :data:`~learner.config.FRAME_PRIOR_MM`
    by default; ``None``: least squares; ``tracker_free``: none on ``T_0_B``).
    ``residual`` (N, 6), what the network adds to the base at ``X``, is taken off the labels
    first, so the frames are fitted to what the base should explain. A nominal base becomes a
    ``frames`` base. Offsets are off by default: from a new day's first 10-100 UR10 points
    they fold local pose error into the encoders (B -> A: 2.76 mm with them, 0.73 mm without,
    BENCHMARKS.md "Real UR10"). Without them the base keeps the frames' posterior spread
    (:func:`frame_sigma_points`): the model's intervals widen where these points fix them
    poorly."""
    desc = base.description
    n = desc.n_joints
    Y = np.asarray(Y, dtype=float) - (0.0 if residual is None else residual)
    obs = base.observations(spec, X, Y)
    free = tuple(5 * i + 4 for i in range(n)) if offsets else ()
    free += tuple(range(5 * n, 5 * n + 12))
    held = [(_Held(e, p), np.zeros(0)) for e, p in base.blocks()]
    candidate = GeometricFrames(desc, free)
    J = jacobian(base.model, obs, [(candidate, np.zeros(len(free))), *held], 1.0, only=0)
    kept = identifiable(J, candidate.parameter_names(desc), CalibrationConfig().rank_rtol)
    frames = GeometricFrames(desc, tuple(free[i] for i in kept.kept_index))
    prior_std = None
    if prior_m is not None:  # each parameter: what moves the tool by prior_m (RMS) here
        prior_std = prior_m / tool_motion_rms(J[:, list(kept.kept_index)])
        if tracker_free:  # T_0_B's six parameters come before the tool's
            prior_std[np.asarray(frames.free) < 5 * n + 6] = np.inf
    blocks = [(frames, np.zeros(len(kept.kept))), *held]
    fit = fit_effects(base.model, obs, blocks, prior_std=prior_std)
    calibrated, T_0_B = apply_calibration(desc, obs.T_W_0, frames.full(fit.params[0]))
    kind = "frames" if base.kind == "nominal" else base.kind
    sigma = None if offsets else frame_sigma_points(desc, obs.T_W_0, frames, fit)
    return replace(base, kind=kind, description=calibrated, T_0_B=T_0_B, frame_sigma=sigma)


def frame_sigma_points(
    desc: RobotDescription, T_W_0: np.ndarray, frames: GeometricFrames, fit: FitResult
) -> np.ndarray | None:
    """The frames one standard deviation out along each principal axis of ``fit``'s posterior
    covariance (its own residual's scale): ``(r, 2, 4, 4)``, each ``T_0_B`` and tool; None when
    nothing was fitted. :meth:`PhysicsBase.frame_variance` turns them into the variance they
    give a prediction, large far from the points that fixed the frames."""
    theta = fit.params[0]
    lam, axes = np.linalg.eigh(fit.cov[: len(theta), : len(theta)])
    out = []
    for value, axis in zip(lam, axes.T, strict=True):
        if value > 1e-12 * lam.max():
            calibrated, T_0_B = apply_calibration(
                desc, T_W_0, frames.full(theta + np.sqrt(value) * axis)
            )
            out.append((T_0_B, calibrated.tool))
    return np.array(out) if out else None


#: How many times the first points' residual (position RMS under the loose prior's frames) the
#: frames must have moved (position RMS of the change over those points) before the carry
#: takes them as moved. A new day's local error fakes a move about its own size (UR10 A <-> B,
#: 10-100 points: 1.0-5.1 x); a tracker moved by 2 mm shows 34-73 x on the simulated cell,
#: 116-131 x on random arms whose base explains the rest, 5.3-15 x on random arms that leave
#: 0.3 mm. Missing a move costs mm, a false one about 0.1 mm (BENCHMARKS.md).
MOVE_EVIDENCE = 5.0


def carried_frames(
    base: PhysicsBase,
    spec: FeatureSpec,
    X: np.ndarray,
    Y: np.ndarray,
    residual: np.ndarray,
    priors: FramePriors,
) -> tuple[PhysicsBase, bool]:
    """A carried base's frames from a new day's first points ``X, Y`` (``residual``: what the
    network adds there) and whether they moved: held near the old ones (``priors.held_m``)
    unless the points show that the tracker or tool moved: frames fitted under the loose
    ``priors.moved_m`` move the predicted positions by more than :data:`MOVE_EVIDENCE` times
    what they leave unexplained (the tracker's frame free in both where ``priors`` say it was
    set up anew). The base's note says which and why."""
    nominal = RobotModel(spec.description)
    free = priors.tracker_free
    fit = partial(reidentify_frames, base, spec, X, Y, residual=residual, tracker_free=free)
    held = fit(prior_m=priors.held_m) if free else None  # a free tracker moves from its own fit
    before = (base if held is None else held).error(spec, X, nominal)[:, :3]
    moved = fit(prior_m=priors.moved_m)
    after = moved.error(spec, X, nominal)[:, :3]
    shift = float(np.sqrt(np.mean(np.sum((after - before) ** 2, axis=1))))
    left = np.asarray(Y, dtype=float)[:, :3] - residual[:, :3] - after
    rms = float(np.sqrt(np.mean(np.sum(left**2, axis=1))))
    is_moved = shift > MOVE_EVIDENCE * rms
    if not is_moved and priors.held_m != priors.moved_m:
        moved = fit(prior_m=priors.held_m) if held is None else held
    verdict, side = ("moved", "over") if is_moved else ("held near the old ones", "under")
    note = (
        f"{'tracker set up anew, its frame free; ' if free else ''}frames {verdict} on {len(X)} "
        f"new points (a free move of {1e3 * shift:.3f} mm against {1e3 * rms:.3f} mm left, "
        f"{side} the {MOVE_EVIDENCE:g} x that shows a move)"
    )
    return replace(moved, note=f"{base.note}; {note}" if base.note else note), is_moved


#: How many times the scale a carry whose frames held starts with (its own times its
#: ``drift_scale``) the day's first points need (the scale
#: :meth:`~learner.model.ErrorModel.calibrate` fits there, geometric mean of x, y, z) before the
#: day is taken as one its model has not seen. Measured against its own scale alone: UR10
#: Series A's first 5,252 points carried to its later days, the same tracker, 2.0-2.9 x (59 % of
#: the day covered); the other way 1.3-1.8 x (58 % covered), which the first points cannot tell
#: from a random half of a random arm's campaign carried to the other half: 0.8-1.5 x, 86-91 %
#: covered (BENCHMARKS.md, "Another day of the same cell"); the drift now covers those days.
MISS_EVIDENCE = 2.0


#: Held-out points of a new day (since ``ContinualLearner.carry``) from which the carried
#: network's gain and the interval scale are re-fitted after each update (a scale fitted on
#: UR10 B's first 10 held-out points covered 68-82 % of the series).
MIN_DAY_POINTS = 20


def unverified(moved: bool, miss: float, n: int) -> str:
    """Why a day carried from its first ``n`` points is not trusted until at least
    :data:`MIN_DAY_POINTS` of its points, :func:`spread` over the workspace, are held out (""
    where it is): its frames moved, or the intervals the carry starts it with (its model's,
    times its drift scale) were more than :data:`MISS_EVIDENCE` times too narrow there
    (``miss``)."""
    if not moved and miss <= MISS_EVIDENCE:
        return ""
    why = (
        "the frames moved" if moved else f"the intervals it came with were {miss:.1f} x too narrow"
    )
    return (
        f"{why} on this day ({n} points); its intervals are checked once at least "
        f"{MIN_DAY_POINTS} of its points, spread over the workspace, are held out"
    )


def position_factor(factors: np.ndarray) -> float:
    """One number for per-component scale factors: the geometric mean of x, y, z."""
    return float(np.exp(np.mean(np.log(factors[:3]))))


def scale_needed(model: ErrorModel, X: np.ndarray, Y: np.ndarray) -> tuple[np.ndarray, float]:
    """The interval scale ``model``, as it comes, needs on a day's first points ``X, Y`` (its
    own left as it was), and how many times its own that is (geometric mean of x, y, z)."""
    own = model.interval_scale.copy()
    try:
        needed = model.calibrate(X, Y)
    finally:
        model.interval_scale = own
    return needed, position_factor(needed / own)


#: Fewest last points in time that measure a model's drift (:func:`drift_scale`).
MIN_DRIFT_POINTS = 50


def drift_scale(
    model: ErrorModel,
    X: np.ndarray,
    Y: np.ndarray,
    t: np.ndarray,
    on_epoch: Callable[[int, float], None] | None = None,
) -> np.ndarray:
    """How many times wider, per component (never narrower), ``model``'s intervals must be on
    points recorded after those it was trained on, ``X, Y`` at times ``t`` (s): a
    :meth:`~ErrorModel.clone` (on ``model``'s base as it is) trained on all but the last
    ``train_cfg.drift_fraction`` of them in time, its scale calibrated as ``fit`` does, over the
    scale those last points need from it. A scale calibrated on a random tenth of the points
    knows how wrong the model is between them, not on a later day: on UR10 Series A's first day
    this is 3.0-3.7 x, and its later days need 2.5-2.7 x (BENCHMARKS.md, "Drift measured in
    training"). Ones where fewer than :data:`MIN_DRIFT_POINTS` are last or the clock never
    moves. ``on_epoch`` follows the clone's training as :meth:`~ErrorModel.fit`'s does."""
    t = np.asarray(t, dtype=float)
    n_last = round(model.train_cfg.drift_fraction * len(t))
    if n_last < MIN_DRIFT_POINTS or not np.ptp(t) > 0:
        return np.ones(Y.shape[1])
    order = np.argsort(t, kind="stable")
    probe = model.clone()
    probe.fit(X[order[:-n_last]], Y[order[:-n_last]], on_epoch=on_epoch)
    needed, _ = scale_needed(probe, X[order[-n_last:]], Y[order[-n_last:]])
    return np.maximum(needed / probe.interval_scale, 1.0)


#: The mark of a model served on a day none of whose points it has seen (:func:`before_day`).
BEFORE_DAY = (
    "a new day: none of its points has checked the frames or the intervals yet (they are "
    "widened by the drift its training measured)"
)


def before_day(model: ErrorModel) -> ErrorModel:
    """A copy of ``model`` as it answers on a new day before any of its points: intervals as
    wide as its ``drift_scale`` says a later day needs, and ``unverified`` (:data:`BEFORE_DAY`)
    until a carry has checked them: nothing yet tells whether the tracker moved overnight.
    Served as it was, UR10 Series A's first day covered 58 % of its later days with 6 % of
    them flagged (BENCHMARKS.md, "Another day of the same cell")."""
    copy = copy_model(model)
    copy.interval_scale = model.interval_scale * model.drift_scale
    copy.unverified = model.unverified or BEFORE_DAY
    return copy


def spread(spec: FeatureSpec, X: np.ndarray, Y: np.ndarray) -> bool:
    """Whether points ``X, Y`` (labels against the nominal) are spread over the workspace: they
    identify the whole geometry, one point per parameter at least, with a condition number at
    most :data:`~learner.base.AUTO_MAX_CONDITION` (the ``auto`` base's rule). A day's first
    points often lie in one region (UR10 Series A's first 800: condition 3.4e3-4.4e3)."""
    nominal = nominal_base(spec.description)
    try:
        ident = identify(nominal.model, nominal.observations(spec, X, Y), CalibrationConfig())
    except IdentifiabilityError:
        return False
    return ident.condition_number <= AUTO_MAX_CONDITION


def hold_day(model: ErrorModel, X: np.ndarray, Y: np.ndarray, mark: str) -> None:
    """Keep the carry's ``mark`` on ``model`` (its ``unverified``) until the day's held-out
    points ``X, Y`` are :func:`spread` over the workspace; clear it then. Points of one region
    cannot check the intervals elsewhere: UR10 B's model carried onto A (frames moved) had
    its mark cleared at A's 20th held-out point, and 40-91 % of the answers it then trusted
    over A's first 800 points (condition 3.4e3-4.4e3) lay inside their 90 % intervals
    (BENCHMARKS.md, "A marked day stays marked")."""
    model.unverified = mark if mark and not spread(model.spec, X, Y) else ""


@dataclass(frozen=True)
class CarriedDay:
    """A carried day's trained points so far (up to ``ContinualConfig.day_frame_points``) and
    the frames ``(T_0_B, tool)`` and note of the base it was carried from, the centre of its
    frames' prior. Frames from the day's first points fold their local error in (they share
    the day's start temperature and one region); fitted again on all its points each time
    they double, that error spreads out: arm 406 of ``sim_sources.unseen``, tracker moved by
    2 mm, ended its day at 0.110 mm on the first points' frames, at 0.061 mm fitted again
    (``bench/learner_moved_day.py``). ``seen_before``: the points the learner had been given
    before the day (so that the day's own count schedules its fresh networks). ``aside``: the
    base a reference program did not start on, its dropped effects in (its frames its own), weighed
    again at each refit (:func:`learner.carry_base.day_frames`); None when nothing is aside."""

    source_frames: np.ndarray
    source_note: str
    x: np.ndarray
    y: np.ndarray
    fitted: int
    seen_before: int = 0
    aside: PhysicsBase | None = None

    @classmethod
    def start(
        cls,
        source: PhysicsBase,
        n_fitted: int,
        n_features: int,
        seen_before: int = 0,
        aside: PhysicsBase | None = None,
    ) -> CarriedDay:
        """A day carried from ``source``, its frames fitted on its first ``n_fitted`` points,
        after ``seen_before`` points of earlier days, with ``aside`` set aside."""
        frames = np.stack([source.T_0_B, source.description.tool])
        empty = np.empty((0, n_features)), np.empty((0, 6))
        return cls(frames, source.note, *empty, n_fitted, seen_before, aside)

    def add(self, X: np.ndarray, Y: np.ndarray, limit: int) -> CarriedDay:
        """With the trained points ``X, Y`` of an update added (none past ``limit``)."""
        room = max(limit - len(self.x), 0)
        x, y = np.concatenate([self.x, X[:room]]), np.concatenate([self.y, Y[:room]])
        return replace(self, x=x, y=y)

    def due(self, limit: int) -> bool:
        """Whether its frames are fitted again now: its points doubled since the last fit, or
        reached ``limit``."""
        n = len(self.x)
        return n > self.fitted and (n >= 2 * self.fitted or n >= limit)

    def source(self, base: PhysicsBase) -> PhysicsBase:
        """``base`` on the frames the day was carried from."""
        T_0_B, tool = self.source_frames
        desc = replace(base.description, tool=tool)
        return replace(base, description=desc, T_0_B=T_0_B, note=self.source_note, frame_sigma=None)

    def swapped(self, base: PhysicsBase) -> CarriedDay:
        """The day carried from its :attr:`aside` instead; ``base``'s geometry and effects on
        the frames it was carried from go aside in turn."""
        assert self.aside is not None
        frames = np.stack([self.aside.T_0_B, self.aside.description.tool])
        return replace(
            self, source_frames=frames, source_note=self.aside.note, aside=self.source(base)
        )

    def holds(self, X: np.ndarray) -> np.ndarray:
        """Which rows of ``X`` are among its points (bool per row)."""
        rows = {row.tobytes() for row in self.x}
        return np.array([row.tobytes() in rows for row in np.asarray(X, dtype=float)], dtype=bool)


class _Held(Effect):
    """An effect held at known parameters while others are fitted (no free parameters)."""

    def __init__(self, effect: Effect, params: np.ndarray) -> None:
        self.effect, self.params, self.name = effect, params, effect.name

    def parameter_names(self, desc: RobotDescription) -> tuple[str, ...]:
        return ()

    def perturbation(self, model: RobotModel, params: np.ndarray, cond: Conditions) -> Perturbation:
        return self.effect.perturbation(model, self.params, cond)
