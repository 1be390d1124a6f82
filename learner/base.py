"""The physics base of the error model: what a kinematic description predicts, so the network
learns only what it leaves.

A base is a description (calibrated DH, tool ``T_6_S``), the pose ``T_0_B`` of its robot frame
in the data's base frame, and the effects ``robocal gap`` named (a model file). Its error
against the nominal model, :meth:`PhysicsBase.error`, is added to the network's residual, so
the model still predicts DESIGN.md's label, the pose error against the nominal. Kinds:

- ``nominal``: the nominal description; the error model is the learner alone;
- ``geometric``: a classical geometric calibration (``robocal calibrate``) of the training points;
- ``gap``: ``robocal gap``'s model of the training points (the geometric calibration plus the
  effects it names that the features can drive), in one step;
- ``auto``: the geometric calibration of the first ``identify_points`` points, or the nominal
  when those points cannot identify it or identify it only ill-conditioned (condition number
  above :data:`AUTO_MAX_CONDITION`: poses from one region; the snapshot says why);
- a path: a calibrated model file (``robocal calibrate --out``) or ``robocal gap``'s model file
  (effects a model's features cannot drive left out, the rest fitted again without them on
  the training points, :func:`refit_base`).

On real UR10 series the geometric and the gap base with a residual network are within a few
per cent (BENCHMARKS.md, "Real UR10": the same on Series A, ``gap`` 7 % better on B); on random
arms whose effects the gap workflow names, ``gap`` reaches the noise floor. So ``robocal
train`` trains on both and keeps ``gap`` where it is better on validation points by a margin
(``best``, :func:`learner.workflow.best_on_validation`).

>>> from kinematics.description import load_description
>>> from learner.features import feature_spec
>>> spec = feature_spec(load_description("ur10"), 0, False)
>>> nominal_base(spec.description).error(spec, np.zeros((2, 6)), None).shape
(2, 6)
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from functools import cached_property
from pathlib import Path

import numpy as np
import pandas as pd

from kinematics.calibration import (
    CalibrationConfig,
    GeometricFrames,
    apply_calibration,
    calibrate,
    fit_under_prior,
    identifiable,
    identify,
)
from kinematics.dataset import (
    Dataset,
    DatasetMeta,
    temperature_column,
    temperature_columns,
    temperature_name,
)
from kinematics.description import RobotDescription
from kinematics.effects import Conditions, Effect, Restricted, perturbed_poses
from kinematics.errors import ConfigError, IdentifiabilityError
from kinematics.gap.model_file import EffectEntry, ModelFile, load_model_file
from kinematics.gap.workflow import run_gap
from kinematics.identification.conditions import Observations, observations_from_dataset
from kinematics.identification.fitting import jacobian
from kinematics.model import RobotModel
from kinematics.transforms import apply_error, invert, pose_error, xyz_quat_from_transform
from learner.config import BASE_KINDS, DEFAULT_BASE, is_model_file
from learner.features import FeatureSpec, temperature_readings

#: Points ``auto`` identifies the geometric base from (the first of the stream).
IDENTIFY_POINTS = 200
#: Largest condition number (unit-norm columns) of an ``auto`` base: the first points of a real
#: stream often lie in one region, where a calibration fits them and extrapolates worse than
#: the nominal (UR10 Series A in time order, 50 points: condition 3.3e3, 1.7 mm off on the rest
#: against 0.77 mm nominal; 9 mm before the calibration prior).
AUTO_MAX_CONDITION = 100.0
#: How a base's note says that it was fitted again (:func:`refit_base`).
_REFIT_NOTE = "; the rest fitted again on"
#: Effects a base evaluates from model features alone (others need signals a model lacks).
_FEATURE_EFFECTS = ("geometric", "joint_compliance", "thermal_expansion", "gear_periodic")


@dataclass(frozen=True, kw_only=True)
class PhysicsBase:
    """Predicted sensor poses from a description, a frame ``T_0_B`` (4, 4) and effects.
    ``condition`` is the condition number the base was identified with (NaN when it was not
    identified from points); ``on_nominal`` marks an ``auto`` base its points left on the
    nominal; ``note`` says the same for people."""

    kind: str
    description: RobotDescription
    T_0_B: np.ndarray
    effects: tuple[EffectEntry, ...] = ()
    note: str = ""
    condition: float = float("nan")
    on_nominal: bool = False
    #: After frames re-identified on few points (:func:`learner.carry.reidentify_frames`): the
    #: frames one standard deviation out along each principal axis of their posterior,
    #: ``(r, 2, 4, 4)``, each ``T_0_B`` and tool; None otherwise.
    frame_sigma: np.ndarray | None = None
    #: Effects of the base's model file that it leaves out (their signals are not features):
    #: its other parameters are fitted again without them where there are points
    #: (:func:`refit_base`; a continual learner as its points double).
    left_out: tuple[str, ...] = ()

    @cached_property
    def model(self) -> RobotModel:
        """The base's kinematic model (built once)."""
        return RobotModel(self.description)

    def blocks(self) -> list[tuple[Effect, np.ndarray]]:
        """The effects with their parameters, ready for :func:`perturbed_poses`."""
        return ModelFile(
            description=self.description, T_W_0=np.eye(4), effects=self.effects
        ).blocks()

    def observations(self, spec: FeatureSpec, X: np.ndarray, Y: np.ndarray) -> Observations:
        """The points ``X, Y`` (labels against the nominal) as observations of the base's
        robot in its frame ``T_0_B``: what its parameters are fitted to again."""
        obs = observations_from_dataset(measured_dataset(spec, X, Y), self.description)
        return replace(obs, T_W_0=self.T_0_B)

    def poses(self, spec: FeatureSpec, X: np.ndarray) -> np.ndarray:
        """Sensor poses ``T_0_S`` ``(N, 4, 4)`` in the data's base frame at raw features ``X``."""
        T = perturbed_poses(self.model, effect_conditions(spec, X), self._blocks)
        return self.T_0_B[None] @ T

    def error(self, spec: FeatureSpec, X: np.ndarray, nominal: RobotModel) -> np.ndarray:
        """The base's pose error ``(N, 6)`` (m, rad) against the ``nominal`` model."""
        if self.kind == "nominal":
            return np.zeros((np.shape(X)[0], 6))
        T_nominal = perturbed_poses(nominal, effect_conditions(spec, X), [])
        return pose_error(self.poses(spec, X), T_nominal)

    def frame_variance(
        self,
        spec: FeatureSpec,
        X: np.ndarray,
        nominal: RobotModel,
        error: np.ndarray | None = None,
    ) -> np.ndarray:
        """The variance ``(N, 6)`` (m², rad²) of :meth:`error` at ``X`` (given, if computed
        already) that the frames' uncertainty gives, linearised along :attr:`frame_sigma`;
        zeros without it."""
        variance = np.zeros((np.shape(X)[0], 6))
        if self.frame_sigma is not None:
            error = self.error(spec, X, nominal) if error is None else error
            for base in self._sigma_bases:
                variance += (base.error(spec, X, nominal) - error) ** 2
        return variance

    @cached_property
    def _sigma_bases(self) -> list[PhysicsBase]:
        return [
            replace(self, description=self.description.with_tool(tool), T_0_B=T, frame_sigma=None)
            for T, tool in self.frame_sigma
        ]

    @cached_property
    def _blocks(self) -> list[tuple[Effect, np.ndarray]]:
        return self.blocks()


def nominal_base(desc: RobotDescription) -> PhysicsBase:
    """The nominal description as a base: the error model is the learner alone."""
    return PhysicsBase(kind="nominal", description=desc, T_0_B=np.eye(4))


def data_frame(ds: Dataset) -> np.ndarray:
    """``T_W_0`` of the frame a dataset's labels are in (identity for base-frame data)."""
    if ds.meta.frame == "base" or ds.meta.T_W_0 is None:
        return np.eye(4)
    return np.asarray(ds.meta.T_W_0, dtype=float)


def measured_dataset(spec: FeatureSpec, X: np.ndarray, Y: np.ndarray) -> Dataset:
    """The measured poses that labels ``Y`` (against the nominal ``spec.description``) encode,
    as a base-frame dataset: what calibration reads, rebuilt from a model's own arrays."""
    desc = spec.description
    X = np.asarray(X, dtype=float)
    T = apply_error(perturbed_poses(RobotModel(desc), effect_conditions(spec, X), []), Y)
    xyz, quat = xyz_quat_from_transform(T)
    columns = {"t": np.arange(len(X), dtype=float)}
    columns |= {f"q{i}": X[:, i - 1] for i in range(1, desc.n_joints + 1)}
    columns |= temperature_readings(spec, X)
    columns |= dict(zip(("x", "y", "z"), xyz.T, strict=True))
    columns |= dict(zip(("qx", "qy", "qz", "qw"), quat.T, strict=True))
    meta = DatasetMeta(robot=desc.name, frame="base", T_6_S=desc.tool.tolist())
    return Dataset(pd.DataFrame(columns), meta)


def identify_base(kind: str, spec: FeatureSpec, X: np.ndarray, Y: np.ndarray) -> PhysicsBase:
    """The base of ``kind`` (:data:`BASE_KINDS`) identified from points ``X, Y`` (labels against
    the nominal): ``auto`` falls back to the nominal where the points cannot identify it."""
    if kind not in BASE_KINDS:
        raise ConfigError(f"base must be one of {BASE_KINDS} or a model file, got {kind!r}")
    if kind == "nominal":
        return nominal_base(spec.description)
    if kind == "gap":
        return gap_base(spec, X, Y)
    n = len(X) if kind == "geometric" else min(len(X), IDENTIFY_POINTS)
    try:
        result = calibrate(spec.description, measured_dataset(spec, X[:n], Y[:n]))
    except IdentifiabilityError as exc:
        if kind == "geometric":
            raise
        nominal = nominal_base(spec.description)
        return replace(nominal, kind=kind, note=f"nominal: {exc}", on_nominal=True)
    cond = result.identifiability.condition_number
    if kind == "auto" and cond > AUTO_MAX_CONDITION:
        note = f"nominal: {n} points identify it with condition number {cond:.3g}"
        note = f"{note} > {AUTO_MAX_CONDITION:g}"
        nominal = nominal_base(spec.description)
        return replace(nominal, kind=kind, note=note, condition=cond, on_nominal=True)
    return PhysicsBase(
        kind=kind,
        description=result.description,
        T_0_B=result.T_W_0,
        note=f"identified from {n} points, condition number {cond:.3g}",
        condition=cond,
    )


def gap_base(spec: FeatureSpec, X: np.ndarray, Y: np.ndarray) -> PhysicsBase:
    """``robocal gap``'s model of the points ``X, Y`` (labels against the nominal) as a base:
    what ``robocal gap`` then ``--base`` its model file would give, in one step."""
    result = run_gap(spec.description, measured_dataset(spec, X, Y))
    named = [e.effect for e in result.named if e.identified]
    shapes = [e.effect for e in result.named if not e.identified]
    before, after = result.stages[0].heldout.mean_mm, result.stages[-1].heldout.mean_mm
    note = f"gap model of {len(X)} points: named {', '.join(named) or 'nothing'}"
    note += f", unnamed corrections of {', '.join(shapes)} shape" if shapes else ""
    note += f"; held-out {before:.4f} -> {after:.4f} mm"
    model = result.model_file()
    base = _model_base("gap", model, model.T_W_0, note)
    return _refitted(base, spec, X, Y) if base.left_out else base


def file_base(
    path: str | Path,
    spec: FeatureSpec,
    frame: np.ndarray,
    X: np.ndarray | None = None,
    Y: np.ndarray | None = None,
) -> PhysicsBase:
    """A calibrated or gap model file as a base, checked against the nominal; ``frame`` is the
    ``T_W_0`` of the data's base frame (the file's ``T_W_0`` is against the same tracker), so
    the file ``robocal gap --report`` writes serves as it is. Where the base leaves effects of
    the file out and there are points ``X, Y`` (labels against the nominal), the rest is fitted
    again without them (:func:`refit_base`)."""
    model = load_model_file(path)
    check_same_robot(model.description, spec.description, f"base file {path}")
    for entry in model.effects:
        needs = [
            n for n in entry.options.get("sensors", []) if temperature_column(n) not in spec.names
        ]
        if needs and entry.name in _FEATURE_EFFECTS:
            raise ConfigError(
                f"base file {path}: effect {entry.name!r} needs {temperature_column(needs[0])}"
            )
    base = _model_base("file", model, invert(frame) @ model.T_W_0, str(path))
    if base.left_out and X is not None and len(X):
        base = _refitted(base, spec, X, Y)
    return base


def refit_base(
    base: PhysicsBase,
    spec: FeatureSpec,
    X: np.ndarray,
    Y: np.ndarray,
    max_condition: float = np.inf,
) -> PhysicsBase:
    """``base`` fitted again to the points ``X, Y`` (labels against the nominal): its geometry
    and frames, and each effect's estimated parameters (those the file gives a std) from their
    values, under calibration's prior. A gap model file's effects were fitted beside backlash
    and tracker drift, which a base leaves out; without them they no longer fit. On UR10 A's points
    3000-4500, ``robocal gap``'s file as a base is 1.19 mm off on the test points, fitted again
    0.39 mm (the geometric base 0.46 mm). IdentifiabilityError where the points cannot
    identify the geometry, or identify all it fits (the effects too; unit-norm columns) only
    with a condition number above ``max_condition``: then nothing is fitted."""
    desc, obs = base.description, base.observations(spec, X, Y)
    ident = identify(base.model, obs, CalibrationConfig())
    geometry = GeometricFrames(desc, ident.kept_index)
    effects = [
        (Restricted(effect, desc, _estimated(entry, effect.parameter_names(desc), params)), params)
        for entry, (effect, params) in zip(base.effects, base.blocks(), strict=True)
    ]
    blocks = [(geometry, np.zeros(len(ident.kept)))]
    blocks += [(effect, params[list(effect.free)]) for effect, params in effects]
    names = tuple(n for block, _ in blocks for n in block.parameter_names(desc))
    J = jacobian(base.model, obs, blocks, 1.0)
    cond = identifiable(J, names, CalibrationConfig().rank_rtol).condition_number
    if cond > max_condition:
        raise IdentifiabilityError(
            f"{len(X)} points identify it with condition number {cond:.3g} > {max_condition:g}"
        )
    fit = fit_under_prior(base.model, obs, blocks, CalibrationConfig())
    calibrated, T_0_B = apply_calibration(desc, obs.T_W_0, geometry.full(fit.params[0]))
    entries = tuple(
        replace(entry, parameters=_named(effect.effect.parameter_names(desc), effect.full(p)))
        for entry, (effect, _), p in zip(base.effects, effects, fit.params[1:], strict=True)
    )
    note = base.note.split(_REFIT_NOTE)[0]  # the latest fit replaces an earlier one
    note += f"{_REFIT_NOTE} {len(X)} points without them, condition number {cond:.3g}"
    return replace(
        base, description=calibrated, T_0_B=T_0_B, effects=entries, note=note, condition=cond
    )


def _refitted(base: PhysicsBase, spec: FeatureSpec, X: np.ndarray, Y: np.ndarray) -> PhysicsBase:
    """:func:`refit_base` on every training point, or ``base`` as it is where they cannot
    identify it (the note says why)."""
    try:
        return refit_base(base, spec, X, Y)
    except IdentifiabilityError as exc:
        return replace(base, note=f"{base.note}; not fitted again: {exc}")


def _estimated(entry: EffectEntry, names: tuple[str, ...], params: np.ndarray) -> tuple[int, ...]:
    """Indices of the parameters a model file's effect estimated: those with a std, or (a file
    that gives none) the non-zero ones."""
    if entry.std:
        return tuple(i for i, name in enumerate(names) if name in entry.std)
    return tuple(map(int, np.flatnonzero(params)))


def _named(names: tuple[str, ...], values: np.ndarray) -> dict[str, float]:
    return dict(zip(names, map(float, values), strict=True))


def _model_base(kind: str, model: ModelFile, T_0_B: np.ndarray, note: str) -> PhysicsBase:
    """A base of a model file's description and effects. Effects that need signals a model's
    features do not carry (backlash: the approach direction; tracker drift: time) are left out
    and named in the note."""
    left_out = [e.name for e in model.effects if e.name not in _FEATURE_EFFECTS]
    if left_out:
        note += (
            f"; left out {', '.join(left_out)}: they need signals a model's features do not carry"
        )
    return PhysicsBase(
        kind=kind,
        description=model.description,
        T_0_B=T_0_B,
        effects=tuple(e for e in model.effects if e.name in _FEATURE_EFFECTS),
        note=note,
        left_out=tuple(left_out),
    )


def make_base(
    base: str, spec: FeatureSpec, X: np.ndarray, Y: np.ndarray, frame: np.ndarray | None = None
) -> PhysicsBase:
    """The base ``base`` names: a kind identified from the training points ``X, Y``, or a model
    file (``.toml``) whose ``T_W_0`` is against the tracker of the data's ``frame``."""
    if is_model_file(base):
        return file_base(base, spec, np.eye(4) if frame is None else frame, X, Y)
    return identify_base(base, spec, X, Y)


def check_same_robot(desc: RobotDescription, nominal: RobotDescription, what: str) -> None:
    """:class:`ConfigError` naming the mismatch when ``desc`` is not ``nominal``'s robot."""
    if desc.n_joints != nominal.n_joints or desc.name != nominal.name:
        raise ConfigError(
            f"{what} is for robot {desc.name!r} ({desc.n_joints} joints), the data is of "
            f"{nominal.name!r} ({nominal.n_joints} joints)"
        )


def effect_conditions(spec: FeatureSpec, X: np.ndarray) -> Conditions:
    """Effect conditions from raw features: joints and named temperatures (no time, no loads)."""
    X = np.asarray(X, dtype=float)
    n = spec.description.n_joints
    temp_idx = [spec.names.index(c) for c in temperature_columns(spec.names)]
    return Conditions(
        q=X[:, :n],
        t=np.zeros(len(X)),
        temperatures=X[:, temp_idx] if temp_idx else None,
        temperature_names=tuple(temperature_name(spec.names[i]) for i in temp_idx),
    )


__all__ = [
    "BASE_KINDS",
    "DEFAULT_BASE",
    "PhysicsBase",
    "check_same_robot",
    "data_frame",
    "gap_base",
    "identify_base",
    "make_base",
    "nominal_base",
    "refit_base",
]
