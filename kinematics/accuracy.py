"""Uncalibrated absolute accuracy of a dataset against its robot's nominal model.

The pose error of DESIGN.md, ``e = [p_m - p_c ; vec(R_m R_c^T)]``, between the measured probe
pose in the base frame (``Dataset.measured_poses_base``) and the nominal FK with the dataset's
``T_6_S`` (else the description's tool), summarised in mm and arcmin.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from kinematics.dataset import Dataset, read_dataset, validate
from kinematics.description import RobotDescription
from kinematics.identity import description_for
from kinematics.model import RobotModel
from kinematics.transforms import pose_error, rotation_angle

ARCMIN_PER_RAD = 60.0 * 180.0 / np.pi


@dataclass(frozen=True, kw_only=True)
class AccuracySummary:
    """Position error statistics (mm), orientation error (arcmin) and the per-point errors."""

    n: int
    mean_mm: float
    std_mm: float
    max_mm: float
    p95_mm: float
    mean_arcmin: float
    max_arcmin: float
    errors_mm: np.ndarray
    errors_arcmin: np.ndarray

    def to_dict(self) -> dict[str, float | int]:
        """The stable scalar keys of ``robocal data summary --json``."""
        keys = ("n", "mean_mm", "std_mm", "max_mm", "p95_mm", "mean_arcmin", "max_arcmin")
        return {k: getattr(self, k) for k in keys}


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
    return AccuracySummary(
        n=int(mm.size),
        mean_mm=float(mm.mean()),
        std_mm=float(mm.std(ddof=1)) if mm.size > 1 else 0.0,
        max_mm=float(mm.max()),
        p95_mm=float(np.percentile(mm, 95)),
        mean_arcmin=float(arcmin.mean()),
        max_arcmin=float(arcmin.max()),
        errors_mm=mm,
        errors_arcmin=arcmin,
    )


def save_histogram(errors_mm: np.ndarray, path: str | Path, title: str = "") -> Path:
    """A PNG histogram of position errors (mm), drawn with matplotlib's Agg backend."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    errors_mm = np.asarray(errors_mm, dtype=float)
    fig = Figure(figsize=(6.0, 4.0), dpi=100)
    FigureCanvasAgg(fig)
    ax = fig.add_subplot()
    ax.hist(errors_mm, bins=min(60, max(5, errors_mm.size // 20)), color="tab:blue")
    ax.axvline(errors_mm.mean(), color="tab:red", label=f"mean {errors_mm.mean():.3f} mm")
    ax.set_xlabel("position error (mm)")
    ax.set_ylabel("points")
    ax.set_title(title or f"uncalibrated position error, N = {errors_mm.size}")
    ax.legend()
    fig.tight_layout()
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, format="png")
    return path


def summarize_file(
    path: str | Path, *, robot: str | None = None, histogram: str | Path | None = None
) -> AccuracySummary:
    """Read a dataset, check it against its robot's limits, summarise; optionally plot.

    ``robot`` (a shipped name or TOML path) defaults to the dataset's ``meta.robot``; either
    is matched to the dataset by :func:`kinematics.identity.description_for`.
    """
    ds = read_dataset(path)
    desc = description_for(ds, robot, path)
    validate(ds, str(path), desc.limits_rad)
    summary = accuracy_summary(ds, desc)
    if histogram is not None:
        save_histogram(summary.errors_mm, histogram, title=f"{Path(path).name} on {desc.name}")
    return summary
