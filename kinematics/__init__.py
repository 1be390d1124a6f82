"""Robot descriptions, pinocchio kinematics, pose errors, frames and the dataset format.

The names below are imported on first use (PEP 562), so that importing a light submodule such
as ``kinematics.errors`` does not load pinocchio, pandas and matplotlib (``robocal --help``).
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from kinematics.lazy import lazy_exports

if TYPE_CHECKING:
    from kinematics.accuracy import AccuracySummary, accuracy_summary
    from kinematics.dataset import Dataset, DatasetMeta, read_dataset, write_dataset
    from kinematics.description import JointDH, RobotDescription, load_description
    from kinematics.errors import RobocalError
    from kinematics.frames import FrameFit, fit_frames, identify_frames, tracker_to_base
    from kinematics.measurability import MeasurabilityConfig, measurability
    from kinematics.model import RobotModel
    from kinematics.transforms import pose_error

_WHERE = {
    "accuracy": ("AccuracySummary", "accuracy_summary"),
    "dataset": ("Dataset", "DatasetMeta", "read_dataset", "write_dataset"),
    "description": ("JointDH", "RobotDescription", "load_description"),
    "errors": ("RobocalError",),
    "frames": ("FrameFit", "fit_frames", "identify_frames", "tracker_to_base"),
    "measurability": ("MeasurabilityConfig", "measurability"),
    "model": ("RobotModel",),
    "transforms": ("pose_error",),
}
__getattr__ = lazy_exports(__name__, _WHERE)


__all__ = [
    "AccuracySummary",
    "FrameFit",
    "MeasurabilityConfig",
    "accuracy_summary",
    "fit_frames",
    "identify_frames",
    "measurability",
    "tracker_to_base",
    "Dataset",
    "DatasetMeta",
    "JointDH",
    "RobocalError",
    "RobotDescription",
    "RobotModel",
    "load_description",
    "pose_error",
    "read_dataset",
    "write_dataset",
]
