"""Uncalibrated absolute accuracy of a dataset against its robot's nominal model.

The pose error of DESIGN.md, ``e = [p_m - p_c ; vec(R_m R_c^T)]``, between the measured probe
pose in the base frame (``Dataset.measured_poses_base``) and the nominal FK with the dataset's
``T_6_S`` (else the description's tool), summarised in mm and arcmin.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from kinematics.dataset import Dataset
from kinematics.description import RobotDescription
from kinematics.error_stats import ErrorStats
from kinematics.model import RobotModel
from kinematics.transforms import ARCMIN_PER_RAD, pose_error, rotation_angle


@dataclass(frozen=True, kw_only=True)
class AccuracySummary(ErrorStats):
    """Position (mm) and orientation (arcmin) error statistics, the per-point errors and the
    robot (description name) they are against."""

    errors_mm: np.ndarray
    errors_arcmin: np.ndarray
    robot: str = ""

    #: The stable scalar keys of ``robocal data summary --json``.
    KEYS = ("n", "mean_mm", "std_mm", "max_mm", "p95_mm", "mean_arcmin", "max_arcmin")


def nominal_poses(ds: Dataset, desc: RobotDescription) -> np.ndarray:
    """Nominal probe poses ``T_0_S`` ``(N, 4, 4)`` with the dataset's ``T_6_S`` if it has one."""
    tool = desc.tool if ds.meta.T_6_S is None else np.asarray(ds.meta.T_6_S, dtype=float)
    return RobotModel(desc.with_tool(tool)).fk(ds.q())


def accuracy_summary(ds: Dataset, desc: RobotDescription) -> AccuracySummary:
    """Uncalibrated position (mm) and orientation (arcmin) accuracy of ``ds`` for ``desc``."""
    nominal = nominal_poses(ds, desc)
    measured = ds.measured_poses_base()
    mm = 1e3 * np.linalg.norm(pose_error(measured, nominal)[:, :3], axis=1)
    dR = measured[:, :3, :3] @ np.swapaxes(nominal[:, :3, :3], 1, 2)
    arcmin = ARCMIN_PER_RAD * rotation_angle(dR)
    return AccuracySummary.of(mm, arcmin, errors_mm=mm, errors_arcmin=arcmin, robot=desc.name)
