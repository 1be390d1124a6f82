"""File-level entry points for the CLI: read a dataset and a description, run, write outputs."""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path

from kinematics.calibration import CalibrationConfig, CalibrationResult, calibrate
from kinematics.dataset import Dataset, read_dataset
from kinematics.description import RobotDescription
from kinematics.gap.model_file import ModelFile, model_to_toml
from kinematics.gap.report import ReportFiles, write_report
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
    report_dir: str | Path | None = None,
    progress: Callable[[str], None] | None = None,
) -> tuple[GapResult, ReportFiles | None]:
    """Run the gap workflow on a dataset file; write the report into ``report_dir`` if given."""
    desc, ds = load_inputs(data, robot)
    result = run_gap(desc, ds, config, progress)
    return result, write_report(result, report_dir) if report_dir is not None else None


def calibrate_from_files(
    data: str | Path,
    robot: str | Path | None = None,
    out: str | Path | None = None,
    config: CalibrationConfig | None = None,
) -> CalibrationResult:
    """Calibrate from a dataset file; write the calibrated model (description + ``T_W_0``) to
    ``out`` if given (the model-file format, without effects)."""
    desc, ds = load_inputs(data, robot)
    result = calibrate(desc, ds, config)
    if out is not None:
        model = ModelFile(description=result.description, T_W_0=result.T_W_0, effects=())
        Path(out).write_text(model_to_toml(model))
    return result


__all__ = ["calibrate_from_files", "gap_from_files", "load_inputs"]
