"""File-level entry points for the CLI: read a dataset and a description, run the workflow.

They return results; the CLI writes them (``stream.reports.gap``).
"""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path

from kinematics.calibration import CalibrationConfig, CalibrationResult, calibrate
from kinematics.gap.workflow import GapConfig, GapResult, run_gap
from kinematics.series import read_series


def gap_from_files(
    data: str | Path,
    robot: str | Path | None = None,
    config: GapConfig | None = None,
    progress: Callable[[str], None] | None = None,
    notify: Callable[[str], None] | None = None,
) -> GapResult:
    """Run the gap workflow on a dataset file (read by :func:`kinematics.series.read_series`,
    whose dropped rows ``notify`` hears of)."""
    desc, ds = read_series(data, robot, notify)
    return run_gap(desc, ds, config, progress)


def calibrate_from_files(
    data: str | Path,
    robot: str | Path | None = None,
    config: CalibrationConfig | None = None,
    notify: Callable[[str], None] | None = None,
) -> CalibrationResult:
    """Calibrate from a dataset file (read as :func:`gap_from_files` reads it)."""
    desc, ds = read_series(data, robot, notify)
    return calibrate(desc, ds, config)


__all__ = ["calibrate_from_files", "gap_from_files"]
