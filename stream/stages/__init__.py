"""Pipeline stages: thin Zenoh shells around the pure cores (one worker thread each)."""

from stream.stages._base import Stage
from stream.stages.compensation_service import CompensationService
from stream.stages.dashboard_stage import DashboardStage
from stream.stages.learner_stage import LearnerStage
from stream.stages.recorder_stage import RecorderStage
from stream.stages.window_stage import WindowStage

__all__ = [
    "CompensationService",
    "DashboardStage",
    "LearnerStage",
    "RecorderStage",
    "Stage",
    "WindowStage",
]
