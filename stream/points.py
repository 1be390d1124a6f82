"""Data points <-> arrays: a batch's joints, deflections, temperatures and base-frame poses
go straight into the learner's one feature builder (:func:`learner.features.features`).

>>> from kinematics.model import RobotModel
>>> from kinematics.description import load_description
>>> from learner.features import feature_spec
>>> from wire import DataPoint
>>> p = DataPoint(seq=0, t=1.0, q=(0.0,) * 6, xyz=(1.0, 0.0, 0.5), quat=(0.0, 0.0, 0.0, 1.0),
...               temperature_names=("ambient",), temperatures=(21.0,))
>>> a = point_arrays([p])
>>> a.features(feature_spec(load_description("ur10"), 1, False, ("ambient",))).tolist()
[[0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 21.0]]
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from kinematics.dataset import (
    POSE_COLUMNS,
    Dataset,
    poses_in_base,
    temperature_columns,
    temperature_name,
)
from kinematics.errors import DatasetError
from kinematics.model import RobotModel
from kinematics.transforms import transform_from_xyz_quat
from learner.features import FeatureSpec, features, labels
from wire import DataPoint


@dataclass(frozen=True)
class PointArrays:
    """The readings of ``N`` data points of one robot as arrays (SI): controller angles
    ``q`` ``(N, n)`` rad, deflections ``qs - q`` ``(N, n)`` rad (None without secondary
    encoders), thermometer channel names, temperatures ``(N, k)`` °C and the measured probe
    poses ``T_0_S`` ``(N, 4, 4)`` in the robot base frame."""

    q: np.ndarray
    deflection: np.ndarray | None
    temperature_names: tuple[str, ...]
    temperatures: np.ndarray
    T_0_S: np.ndarray

    def features(self, spec: FeatureSpec) -> np.ndarray:
        """Raw SI features ``(N, F)`` in ``spec.names`` order."""
        temps = dict(zip(self.temperature_names, self.temperatures.T, strict=True))
        return features(spec, self.q, self.deflection, temps)

    def labels(self, model: RobotModel) -> np.ndarray:
        """Labels ``(N, 6)`` against the nominal ``model`` (m, rad)."""
        return labels(model, self.q, self.T_0_S)


def point_arrays(points: Sequence[DataPoint], T_W_0: np.ndarray | None = None) -> PointArrays:
    """The arrays of ``points``; all must share frame, joint count and thermometers (a point
    without the secondary encoders the first has reads NaN). Tracker-frame poses need
    ``T_W_0``."""
    if not points:
        raise DatasetError("no data points to convert")
    first = points[0]
    n = len(first.q)
    for p in points:
        if (
            p.frame != first.frame
            or len(p.q) != n
            or p.temperature_names != first.temperature_names
            or len(p.temperatures) != len(p.temperature_names)
            or (p.qs is not None and len(p.qs) != n)
        ):
            raise DatasetError(
                f"point seq {p.seq}: frame/joints/thermometers differ from point seq {first.seq}"
            )
    q = np.array([p.q for p in points], dtype=float)
    deflection = None
    if first.qs is not None:
        qs = np.array([p.qs or [np.nan] * n for p in points], dtype=float)
        deflection = qs - q
    temps = np.array([p.temperatures for p in points], dtype=float).reshape(len(points), -1)
    T = transform_from_xyz_quat(
        np.array([p.xyz for p in points], dtype=float),
        np.array([p.quat for p in points], dtype=float),
    )
    return PointArrays(
        q=q,
        deflection=deflection,
        temperature_names=first.temperature_names,
        temperatures=temps,
        T_0_S=poses_in_base(T, first.frame, T_W_0),
    )


def dataset_to_points(ds: Dataset) -> list[DataPoint]:
    """The data points of a dataset's rows (``seq`` = row index)."""
    t = ds.table
    q = ds.q()
    qs = None if ds.deflection() is None else q + ds.deflection()
    temp_cols = temperature_columns(t)
    temps = t[temp_cols].to_numpy(float) if temp_cols else np.zeros((len(t), 0))
    names = tuple(temperature_name(c) for c in temp_cols)
    pose = t[list(POSE_COLUMNS)].to_numpy(float)
    times = t["t"].to_numpy(float)
    return [
        DataPoint(
            seq=i,
            t=float(times[i]),
            q=tuple(q[i].tolist()),
            qs=None if qs is None else tuple(qs[i].tolist()),
            xyz=tuple(pose[i, :3].tolist()),
            quat=tuple(pose[i, 3:].tolist()),
            frame=ds.meta.frame,
            temperature_names=names,
            temperatures=tuple(temps[i].tolist()),
        )
        for i in range(len(t))
    ]
