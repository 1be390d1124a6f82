"""Robot descriptions, pinocchio kinematics, pose errors, frames and the dataset format."""

from kinematics.dataset import Dataset, DatasetMeta, read_dataset, write_dataset
from kinematics.description import JointDH, RobotDescription, load_description
from kinematics.errors import RobocalError
from kinematics.model import RobotModel
from kinematics.transforms import pose_error

__all__ = [
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
