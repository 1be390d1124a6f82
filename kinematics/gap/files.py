"""File-level entry points for the CLI: read a dataset and a description, run the workflow.

They return results; the CLI writes them (``stream.reports.gap``).
"""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path

from kinematics.calibration import CalibrationConfig, CalibrationResult, calibrate
from kinematics.dataset import Dataset, read_dataset
from kinematics.description import RobotDescription
from kinematics.gap.workflow import GapConfig, GapResult, run_gap
from kinematics.identity import description_for


def load_inputs(data: str | Path, robot: str | Path | None) -> tuple[RobotDescription, Dataset]:
    """The dataset at ``data`` and the description ``robot`` (default: the dataset's robot),
    matched by :func:`kinematics.identity.description_for`."""
    ds = read_dataset(data)
    return description_for(ds, robot, data), ds


def gap_from_files(
    data: str | Path,
    robot: str | Path | None = None,
    config: GapConfig | None = None,
    progress: Callable[[str], None] | None = None,
) -> GapResult:
    """Run the gap workflow on a dataset file."""
    desc, ds = load_inputs(data, robot)
    return run_gap(desc, ds, config, progress)


def calibrate_from_files(
    data: str | Path,
    robot: str | Path | None = None,
    config: CalibrationConfig | None = None,
) -> CalibrationResult:
    """Calibrate from a dataset file."""
    desc, ds = load_inputs(data, robot)
    return calibrate(desc, ds, config)


__all__ = ["calibrate_from_files", "gap_from_files", "load_inputs"]
