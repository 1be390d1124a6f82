"""The learner: deep evidential ensemble, max-error replay, training, snapshots and metrics.

Depends on ``kinematics`` only. The estimator is :class:`ErrorModel`; continual learning runs
through :class:`ContinualLearner`; weights travel as safetensors via :mod:`learner.snapshot`.
"""

from learner.config import ContinualConfig, ModelConfig, TrainConfig
from learner.continual import ContinualLearner, UpdateMetrics
from learner.evidential import Evidential
from learner.features import FeatureSpec, dataset_features, dataset_labels, feature_spec
from learner.metrics import AccuracyReport, accuracy_report
from learner.model import ErrorModel, TrainReport
from learner.replay import REPLAY_STRATEGIES, ReplayStrategy
from learner.snapshot import load_snapshot, save_snapshot, snapshot_from_bytes, snapshot_to_bytes

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
