"""Robot descriptions, pinocchio kinematics, pose errors, frames and the dataset format."""

from kinematics.accuracy import AccuracySummary, accuracy_summary
from kinematics.dataset import Dataset, DatasetMeta, read_dataset, write_dataset
from kinematics.description import JointDH, RobotDescription, load_description
from kinematics.errors import RobocalError
from kinematics.frames import FrameFit, fit_frames, identify_frames, tracker_to_base
from kinematics.measurability import MeasurabilityConfig, measurability
from kinematics.model import RobotModel
from kinematics.transforms import pose_error

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
