"""Features and labels from arrays, with fixed min-max scaling from the robot description.

Features are the controller joint angles ``q1..qn`` (rad), the elastic deflections
``dtheta1..n = qs - q`` (rad, when secondary encoders exist) and temperatures ``temp_<name>``
(°C). Their scaling ranges come from the description's joint limits and declared sensor ranges,
never from data, so the scaling of a streaming model never changes.

:func:`features` and :func:`labels` are the one builder from arrays: training reads them from a
dataset (:func:`dataset_features`, :func:`dataset_labels`), the learner stage and the dashboard
from data points (:mod:`stream.points`), compensation from a request.

>>> from kinematics.description import load_description
>>> spec = feature_spec(load_description("ur10"), n_temperatures=1, has_secondary=False)
>>> spec.names
('q1', 'q2', 'q3', 'q4', 'q5', 'q6', 'temp_1')
>>> spec.scale(np.array([[0, 0, 0, 0, 0, 0, 30.0]]))[0, -1]
np.float64(0.0)
"""

from __future__ import annotations

import functools
import re
from collections.abc import Mapping
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from kinematics.dataset import (
    TEMPERATURE_PREFIX,
    Dataset,
    secondary_columns,
    temperature_column,
    temperature_columns,
)
from kinematics.description import RobotDescription
from kinematics.errors import ConfigError, DatasetError
from kinematics.transforms import pose_error

if TYPE_CHECKING:  # pinocchio is only needed by callers that compute labels
    from kinematics.model import RobotModel


@dataclass(frozen=True, kw_only=True)
class FeatureSpec:
    """Feature names and the fixed ranges ``[low, high]`` mapped to ``[-1, 1]`` (SI units), with
    the robot description the kinematic input encoding needs (:mod:`learner.encoding`)."""

    names: tuple[str, ...]
    low: np.ndarray
    high: np.ndarray
    description: RobotDescription | None = None

    def __post_init__(self) -> None:
        low = np.asarray(self.low, dtype=float).reshape(-1)
        high = np.asarray(self.high, dtype=float).reshape(-1)
        if not (len(self.names) == low.size == high.size):
            raise ConfigError(
                f"feature spec needs one range per name: {len(self.names)} names, "
                f"{low.size} lows, {high.size} highs"
            )
        if not self.names:
            raise ConfigError("feature spec needs at least one feature, got none")
        bad = np.flatnonzero(~(low < high))
        if bad.size:
            raise ConfigError(
                f"feature {self.names[bad[0]]!r}: range must satisfy low < high, got "
                f"[{low[bad[0]]}, {high[bad[0]]}]"
            )
        object.__setattr__(self, "names", tuple(self.names))
        object.__setattr__(self, "low", low)
        object.__setattr__(self, "high", high)

    @property
    def n_features(self) -> int:
        return len(self.names)

    @property
    def n_joints(self) -> int:
        """How many joint angles ``q1..qn`` the features hold (the leading columns)."""
        return _plan(self.names).n_joints

    def scale(self, X: np.ndarray) -> np.ndarray:
        """Raw SI features ``(N, F)`` -> ``[-1, 1]`` over the declared ranges."""
        X = np.asarray(X, dtype=float)
        if X.ndim != 2 or X.shape[1] != self.n_features:
            raise DatasetError(
                f"features must have shape (N, {self.n_features}) for {self.names}, got {X.shape}"
            )
        return 2.0 * (X - self.low) / (self.high - self.low) - 1.0


def feature_spec(
    desc: RobotDescription,
    n_temperatures: int,
    has_secondary: bool,
    temperature_names: tuple[str, ...] | list[str] = (),
) -> FeatureSpec:
    """The features a robot provides: joints, optionally deflections and ``n_temperatures``
    thermometers (named ``temp_<name>``, or ``temp_1..`` without names)."""
    if n_temperatures < 0:
        raise ConfigError(f"n_temperatures must be >= 0, got {n_temperatures}")
    temps = tuple(temperature_names) or tuple(str(i) for i in range(1, n_temperatures + 1))
    if len(temps) != n_temperatures:
        raise ConfigError(
            f"temperature_names must name {n_temperatures} thermometers, got {len(temps)}"
        )
    n = desc.n_joints
    limits = desc.limits_rad
    names = [f"q{i}" for i in range(1, n + 1)]
    low, high = list(limits[:, 0]), list(limits[:, 1])
    if has_secondary:
        d = desc.sensors.deflection_max_rad
        names += [f"dtheta{i}" for i in range(1, n + 1)]
        low += [-d] * n
        high += [d] * n
    names += [temperature_column(t) for t in temps]
    low += [desc.sensors.temperature_min_c] * n_temperatures
    high += [desc.sensors.temperature_max_c] * n_temperatures
    return FeatureSpec(names=tuple(names), low=np.array(low), high=np.array(high), description=desc)


def dataset_feature_spec(
    ds: Dataset, desc: RobotDescription, *, secondary: bool = True, temperatures: bool = True
) -> FeatureSpec:
    """The spec of every feature ``ds`` has (or a subset: no deflections, no temperatures)."""
    has_secondary = secondary and bool(secondary_columns(ds.table))
    temps = temperature_columns(ds.table) if temperatures else []
    return feature_spec(desc, len(temps), has_secondary, tuple(temps))


def features(
    spec: FeatureSpec,
    q: np.ndarray,
    deflection: np.ndarray | None = None,
    temperatures: Mapping[str, np.ndarray | float] | None = None,
) -> np.ndarray:
    """Raw SI features ``(N, F)`` in ``spec.names`` order from controller angles ``q`` ``(N, n)``
    (rad), deflections ``qs - q`` ``(N, n)`` (rad) and temperatures (°C, ``(N,)`` or one value,
    by channel or column name); a :class:`DatasetError` names the first input missing."""
    plan = _plan(spec.names)
    q = np.asarray(q, dtype=float)
    if q.ndim != 2:
        raise DatasetError(f"joint angles must have shape (N, n), got {q.shape}")
    if plan.n_joints > q.shape[1]:
        raise DatasetError(f"no joint angle q{q.shape[1] + 1} for feature 'q{q.shape[1] + 1}'")
    parts = [q[:, plan.q]]
    if plan.dtheta.size:
        n = 0 if deflection is None else np.shape(deflection)[1]
        if plan.n_deflections > n:
            raise DatasetError(f"no deflection (secondary encoder qs{n + 1}) for 'dtheta{n + 1}'")
        parts.append(np.asarray(deflection, dtype=float)[:, plan.dtheta])
    if plan.temps:
        temps = {temperature_column(k): v for k, v in (temperatures or {}).items()}
        missing = [c for c in plan.temps if c not in temps]
        if missing:
            have = ", ".join(sorted(temps)) or "none"
            raise DatasetError(
                f"no thermometer {missing[0]!r}, which the model reads (the data has: {have})"
            )
        try:  # (k,) one value per thermometer, or (k, N) one per point
            values = np.array([temps[c] for c in plan.temps], dtype=float)
        except ValueError:
            raise DatasetError("temperatures must all be single values or all arrays") from None
        parts.append(values.T if values.ndim == 2 else np.repeat(values[None], len(q), axis=0))
    X = np.concatenate(parts, axis=1)
    return X if plan.order is None else X[:, plan.order]


#: A feature name: ``q<i>`` or ``dtheta<i>`` (joint ``i``, from 1), or a temperature column.
_FEATURE = re.compile(rf"(q|dtheta)([1-9][0-9]*)|{re.escape(TEMPERATURE_PREFIX)}.+")


@dataclass(frozen=True)
class _Plan:
    """Where each feature is read: joints (zero-based) of the ``q`` and ``dtheta`` features,
    the temperature columns, the permutation from ``[q | dtheta | temps]`` to the spec's
    order (None when it is that order already), and how many joints the angles and the
    deflections must have."""

    q: np.ndarray
    dtheta: np.ndarray
    temps: tuple[str, ...]
    order: np.ndarray | None
    n_joints: int
    n_deflections: int


@functools.lru_cache(maxsize=64)
def _plan(names: tuple[str, ...]) -> _Plan:
    """The :class:`_Plan` of feature names, parsed once per spec (compensation builds one row
    per solver step)."""
    where: dict[str, list[int]] = {"q": [], "dtheta": [], "temp": []}  # spec columns per kind
    joints: dict[str, list[int]] = {"q": [], "dtheta": []}
    temps = []
    for col, name in enumerate(names):
        match = _FEATURE.fullmatch(name)
        if match is None:
            raise DatasetError(f"unknown feature {name!r}: expected q<i>, dtheta<i> or temp_<name>")
        kind = match[1] or "temp"
        where[kind].append(col)
        if kind == "temp":
            temps.append(name)
        else:
            joints[kind].append(int(match[2]) - 1)
    cols = where["q"] + where["dtheta"] + where["temp"]
    return _Plan(
        q=np.array(joints["q"], dtype=int),
        dtheta=np.array(joints["dtheta"], dtype=int),
        temps=tuple(temps),
        order=None if cols == sorted(cols) else np.argsort(cols),
        n_joints=max(joints["q"], default=-1) + 1,
        n_deflections=max(joints["dtheta"], default=-1) + 1,
    )


def labels(model: RobotModel, q: np.ndarray, T_0_S: np.ndarray) -> np.ndarray:
    """Labels ``(N, 6)``: the pose error of the measured probe poses ``T_0_S`` ``(N, 4, 4)``
    (robot base frame) against nominal FK at controller angles ``q`` (m, rad)."""
    return pose_error(T_0_S, model.fk(q))


def temperature_readings(spec: FeatureSpec, X: np.ndarray) -> dict[str, np.ndarray]:
    """The thermometer columns of raw features ``X`` ``(N, F)`` by feature name (°C)."""
    X = np.asarray(X, dtype=float)
    return {name: X[:, spec.names.index(name)] for name in temperature_columns(spec.names)}


def dataset_features(ds: Dataset, spec: FeatureSpec) -> np.ndarray:
    """Raw SI features ``(N, F)`` of ``ds`` in ``spec.names`` order."""
    t = ds.table
    temps = {c: t[c].to_numpy(float) for c in temperature_columns(t)}  # all: an error names them
    deflection = ds.deflection() if _plan(spec.names).dtheta.size else None
    return features(spec, ds.q(), deflection, temps)


def dataset_labels(ds: Dataset, model: RobotModel) -> np.ndarray:
    """Labels ``(N, 6)``: the pose error of the measured ``T_0_S`` against nominal FK (m, rad)."""
    return labels(model, ds.q(), ds.measured_poses_base())
