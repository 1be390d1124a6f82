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
from kinematics.dataset import Dataset, check_joint_limits, read_dataset
from kinematics.description import RobotDescription
from kinematics.frames import fit_frames_screened
from kinematics.identity import description_for
from kinematics.model import RobotModel
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


def judged_errors(ds: Dataset, desc: RobotDescription) -> np.ndarray:
    """The pose errors (N, 6; m and rad) a series is judged by: against the nominal model, in
    the base frame; tracker-frame poses whose ``T_W_0`` the metadata lacks, against frames
    fitted to them (:func:`kinematics.frames.fit_frames_screened`), as calibration fits them:
    as measured, metres from the base and turned, one row 1 m off in Series B lay 16 robust
    units out."""
    if ds.meta.frame == "base" or ds.meta.T_W_0 is not None:
        return pose_error(ds.measured_poses_base(), nominal_poses(ds, desc))
    tool = desc.tool if ds.meta.T_6_S is None else np.asarray(ds.meta.T_6_S, dtype=float)
    flange = RobotModel(desc).fk(ds.q(), frame="flange")
    fit = fit_frames_screened(ds.measured_poses(), flange, T_6_S_init=tool)[0]
    return pose_error(ds.measured_poses(), fit.T_W_0[None] @ flange @ fit.T_6_S[None])


def without_gross_outliers(
    ds: Dataset, desc: RobotDescription
) -> tuple[Dataset, DroppedRows | None]:
    """``ds`` without its gross outliers against ``desc``, and what was dropped (None: none)."""
    errors = judged_errors(ds, desc)
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
    ds = read_dataset(path)  # validated, all but the joint limits its description gives
    desc = description_for(ds, robot, path)
    check_joint_limits(ds, str(path), desc.limits_rad)
    ds, dropped = without_gross_outliers(ds, desc)
    if dropped is not None and notify is not None:
        notify(dropped.notice(str(path)))
    return desc, ds


__all__ = ["DroppedRows", "judged_errors", "read_series", "without_gross_outliers"]
