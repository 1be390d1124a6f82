"""Features and labels from a dataset, with fixed min-max scaling from the robot description.

Features are the controller joint angles ``q1..qn`` (rad), the elastic deflections
``dtheta1..n = qs - q`` (rad, when secondary encoders exist) and temperatures ``temp_<name>``
(°C). Their scaling ranges come from the description's joint limits and declared sensor ranges,
never from data, so the scaling of a streaming model never changes.

>>> from kinematics.description import load_description
>>> spec = feature_spec(load_description("ur10"), n_temperatures=1, has_secondary=False)
>>> spec.names
('q1', 'q2', 'q3', 'q4', 'q5', 'q6', 'temp_1')
>>> spec.scale(np.array([[0, 0, 0, 0, 0, 0, 30.0]]))[0, -1]
np.float64(0.0)
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from kinematics.dataset import Dataset, joint_columns, secondary_columns
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
    names += [t if t.startswith("temp_") else f"temp_{t}" for t in temps]
    low += [desc.sensors.temperature_min_c] * n_temperatures
    high += [desc.sensors.temperature_max_c] * n_temperatures
    return FeatureSpec(names=tuple(names), low=np.array(low), high=np.array(high), description=desc)


def dataset_feature_spec(
    ds: Dataset, desc: RobotDescription, *, secondary: bool = True, temperatures: bool = True
) -> FeatureSpec:
    """The spec of every feature ``ds`` has (or a subset: no deflections, no temperatures)."""
    has_secondary = secondary and bool(secondary_columns(ds.table))
    temps = [c for c in ds.table.columns if c.startswith("temp_")] if temperatures else []
    return feature_spec(desc, len(temps), has_secondary, tuple(temps))


def dataset_features(ds: Dataset, spec: FeatureSpec) -> np.ndarray:
    """Raw SI features ``(N, F)`` of ``ds`` in ``spec.names`` order."""
    t = ds.table
    qcols = joint_columns(t)
    cols = []
    for name in spec.names:
        if name.startswith("dtheta"):
            i = int(name[len("dtheta") :])
            if f"qs{i}" not in t.columns or f"q{i}" not in t.columns:
                raise DatasetError(f"dataset has no column 'qs{i}' for feature {name!r}")
            cols.append(t[f"qs{i}"].to_numpy(float) - t[f"q{i}"].to_numpy(float))
        elif name in t.columns and (name in qcols or name.startswith("temp_")):
            cols.append(t[name].to_numpy(float))
        else:
            raise DatasetError(f"dataset has no column {name!r} for feature {name!r}")
    return np.stack(cols, axis=1) if cols else np.empty((len(t), 0))


def dataset_labels(ds: Dataset, model: RobotModel) -> np.ndarray:
    """Labels ``(N, 6)``: the pose error of the measured ``T_0_S`` against nominal FK (m, rad)."""
    return pose_error(ds.measured_poses_base(), model.fk(ds.q()))
