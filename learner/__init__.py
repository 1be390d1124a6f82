"""The learner: deep evidential ensemble, max-error replay, training, snapshots and metrics.

Depends on ``kinematics`` only. The estimator is :class:`ErrorModel`; continual learning runs
through :class:`ContinualLearner`; weights travel as safetensors via :mod:`learner.snapshot`.
The names below are imported on first use (PEP 562), so that importing a light submodule such
as ``learner.config`` does not load torch (``robocal --help``).
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from kinematics.lazy import lazy_exports

if TYPE_CHECKING:
    from learner.config import ContinualConfig, ModelConfig, TrainConfig
    from learner.continual import ContinualLearner
    from learner.continual_records import UpdateMetrics
    from learner.evidential import Evidential
    from learner.features import FeatureSpec, dataset_features, dataset_labels, feature_spec
    from learner.metrics import AccuracyReport, accuracy_report
    from learner.model import ErrorModel, TrainReport
    from learner.replay import REPLAY_STRATEGIES, ReplayStrategy
    from learner.snapshot import (
        load_snapshot,
        save_snapshot,
        snapshot_from_bytes,
        snapshot_to_bytes,
    )

_WHERE = {
    "config": ("ContinualConfig", "ModelConfig", "TrainConfig"),
    "continual": ("ContinualLearner",),
    "continual_records": ("UpdateMetrics",),
    "evidential": ("Evidential",),
    "features": ("FeatureSpec", "dataset_features", "dataset_labels", "feature_spec"),
    "metrics": ("AccuracyReport", "accuracy_report"),
    "model": ("ErrorModel", "TrainReport"),
    "replay": ("REPLAY_STRATEGIES", "ReplayStrategy"),
    "snapshot": ("load_snapshot", "save_snapshot", "snapshot_from_bytes", "snapshot_to_bytes"),
}
__getattr__ = lazy_exports(__name__, _WHERE)


__all__ = [
    "REPLAY_STRATEGIES",
    "AccuracyReport",
    "ContinualConfig",
    "ContinualLearner",
    "ErrorModel",
    "Evidential",
    "FeatureSpec",
    "ModelConfig",
    "ReplayStrategy",
    "TrainConfig",
    "TrainReport",
    "UpdateMetrics",
    "accuracy_report",
    "dataset_features",
    "dataset_labels",
    "feature_spec",
    "load_snapshot",
    "save_snapshot",
    "snapshot_from_bytes",
    "snapshot_to_bytes",
]
