"""Data points ↔ the dataset format, so the learner's feature and label functions apply as-is.

>>> from wire import DataPoint
>>> p = DataPoint(seq=0, t=1.0, q=(0.0,) * 6, xyz=(1.0, 0.0, 0.5), quat=(0.0, 0.0, 0.0, 1.0),
...               temperature_names=("ambient",), temperatures=(21.0,))
>>> ds = points_to_dataset([p], robot="ur10")
>>> list(ds.table.columns)[:3], ds.temperatures().tolist()
(['t', 'q1', 'q2'], [[21.0]])
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
import pandas as pd

from kinematics.dataset import POSE_COLUMNS, Dataset, DatasetMeta
from kinematics.errors import DatasetError
from wire import DataPoint


def temperature_column(name: str) -> str:
    """The dataset column of a thermometer: ``temp_<name>``."""
    return name if name.startswith("temp_") else f"temp_{name}"


def points_to_dataset(
    points: Sequence[DataPoint], robot: str, T_W_0: np.ndarray | None = None
) -> Dataset:
    """A dataset (DESIGN.md format) of points; all must share frame, joint count, sensors."""
    if not points:
        raise DatasetError("no data points to convert")
    first = points[0]
    n = len(first.q)
    rows = []
    for p in points:
        if (
            p.frame != first.frame
            or len(p.q) != n
            or p.temperature_names != first.temperature_names
        ):
            raise DatasetError(
                f"point seq {p.seq}: frame/joints/thermometers differ from point seq {first.seq}"
            )
        row = {"t": p.t}
        row.update({f"q{i + 1}": v for i, v in enumerate(p.q)})
        if first.qs is not None:
            row.update({f"qs{i + 1}": v for i, v in enumerate(p.qs or [np.nan] * n)})
        row.update(
            {
                temperature_column(k): v
                for k, v in zip(p.temperature_names, p.temperatures, strict=True)
            }
        )
        row.update(dict(zip(POSE_COLUMNS, (*p.xyz, *p.quat), strict=True)))
        rows.append(row)
    meta = DatasetMeta(
        robot=robot,
        frame=first.frame,
        T_W_0=None if T_W_0 is None else np.asarray(T_W_0, dtype=float).tolist(),
    )
    return Dataset(pd.DataFrame(rows), meta)


def dataset_to_points(ds: Dataset) -> list[DataPoint]:
    """The data points of a dataset's rows (``seq`` = row index)."""
    t = ds.table
    q = ds.q()
    qs = None if ds.deflection() is None else q + ds.deflection()
    temp_cols = [c for c in t.columns if c.startswith("temp_")]
    temps = t[temp_cols].to_numpy(float) if temp_cols else np.zeros((len(t), 0))
    names = tuple(c[len("temp_") :] for c in temp_cols)
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
