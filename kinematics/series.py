"""A measured series read for calibration or learning: every joint angle checked against the
robot's limits, and the gross outliers (:mod:`kinematics.outliers`) dropped and named.

Every command that fits, learns from or summarises a dataset file reads it here (``calibrate``,
``gap``, ``train``, ``continual``, ``evaluate``, ``hpo``, ``experiment paper``, ``data
summary``), so one lost tracker beam cannot decide a fit.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from kinematics.accuracy import nominal_poses
from kinematics.dataset import Dataset, read_dataset, validate
from kinematics.description import RobotDescription
from kinematics.identity import description_for
from kinematics.outliers import GROSS_THRESHOLD, gross_outliers
from kinematics.transforms import pose_error


@dataclass(frozen=True, kw_only=True)
class DroppedRows:
    """Gross outliers dropped from a series: their ``rows`` in the file and their position
    errors against the nominal model (mm)."""

    rows: tuple[int, ...]
    errors_mm: tuple[float, ...]
    n_rows: int

    def notice(self, source: str) -> str:
        """One line naming the rows dropped and how far off they were."""
        shown = ", ".join(map(str, self.rows[:5]))
        more = f" and {len(self.rows) - 5} more" if len(self.rows) > 5 else ""
        return (
            f"{source}: dropped {len(self.rows)} of {self.n_rows} rows as gross outliers (row "
            f"{shown}{more}; up to {max(self.errors_mm):.1f} mm from the nominal model, over "
            f"{GROSS_THRESHOLD:g} robust units from the series' own errors)"
        )


def without_gross_outliers(
    ds: Dataset, desc: RobotDescription
) -> tuple[Dataset, DroppedRows | None]:
    """``ds`` without its gross outliers against ``desc``, and what was dropped (None: none).
    Tracker-frame poses whose ``T_W_0`` is unknown are judged as they are, as they are learned."""
    unknown_frame = ds.meta.frame == "tracker" and ds.meta.T_W_0 is None
    measured = ds.measured_poses() if unknown_frame else ds.measured_poses_base()
    errors = pose_error(measured, nominal_poses(ds, desc))
    rows = gross_outliers(errors)
    if not len(rows):
        return ds, None
    dropped = DroppedRows(
        rows=tuple(int(r) for r in rows),
        errors_mm=tuple(float(e) for e in 1e3 * np.linalg.norm(errors[rows, :3], axis=1)),
        n_rows=len(ds),
    )
    return ds.subset(np.setdiff1d(np.arange(len(ds)), rows)), dropped


def read_series(
    path: str | Path,
    robot: str | Path | None = None,
    notify: Callable[[str], None] | None = None,
) -> tuple[RobotDescription, Dataset]:
    """The dataset at ``path`` and its description (``robot``, default the dataset's own,
    matched by :func:`kinematics.identity.description_for`), every joint angle checked against
    the description's limits and the gross outliers dropped; ``notify`` hears of those."""
    ds = read_dataset(path)
    desc = description_for(ds, robot, path)
    validate(ds, str(path), desc.limits_rad)
    ds, dropped = without_gross_outliers(ds, desc)
    if dropped is not None and notify is not None:
        notify(dropped.notice(str(path)))
    return desc, ds


__all__ = ["DroppedRows", "read_series", "without_gross_outliers"]
