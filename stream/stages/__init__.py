"""Pipeline stages: thin Zenoh shells around the pure cores (one worker thread each).

The registry :data:`STAGES` names every stage and the class that builds it, in data-flow order
(the order the daemon closes them); a robot's ``stages`` may list the per-robot ones
(:data:`ROBOT_STAGES`), the recorder is the cell's. Classes load on first use (PEP 562), so
checking a config's stage names does not load zenoh, torch or rerun. Every registered stage
passes ``tests/stream/test_stage_conformance.py``.
"""

from __future__ import annotations

from importlib import import_module
from typing import TYPE_CHECKING, Any

from kinematics.errors import ConfigError

if TYPE_CHECKING:
    from stream.stages._base import Stage
    from stream.stages.compensation_service import CompensationService
    from stream.stages.dashboard_stage import DashboardStage
    from stream.stages.learner_stage import LearnerStage
    from stream.stages.recorder_stage import RecorderStage
    from stream.stages.window_stage import WindowStage

#: Stage name -> (module, class), in data-flow order: the one list of stage names.
STAGES: dict[str, tuple[str, str]] = {
    "window": ("stream.stages.window_stage", "WindowStage"),
    "learner": ("stream.stages.learner_stage", "LearnerStage"),
    "compensation": ("stream.stages.compensation_service", "CompensationService"),
    "dashboard": ("stream.stages.dashboard_stage", "DashboardStage"),
    "recorder": ("stream.stages.recorder_stage", "RecorderStage"),
}
#: The stages one per robot (what ``[[robots]] stages`` may list); the recorder is per cell.
ROBOT_STAGES: tuple[str, ...] = tuple(name for name in STAGES if name != "recorder")
_CLASSES = {cls: module for module, cls in STAGES.values()} | {"Stage": "stream.stages._base"}


def stage_class(name: str) -> type[Stage]:
    """The class of the stage ``name`` (ConfigError naming the known stages otherwise)."""
    if name not in STAGES:
        raise ConfigError(f"unknown stage {name!r}; known: {', '.join(STAGES)}")
    module, cls = STAGES[name]
    return getattr(import_module(module), cls)


def __getattr__(name: str) -> Any:
    """The exported stage class ``name``, importing its module on first use."""
    if name not in _CLASSES:
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    return getattr(import_module(_CLASSES[name]), name)


__all__ = [
    "ROBOT_STAGES",
    "STAGES",
    "CompensationService",
    "DashboardStage",
    "LearnerStage",
    "RecorderStage",
    "Stage",
    "WindowStage",
    "stage_class",
]
