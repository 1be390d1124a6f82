"""Fixtures shared by the stream tests."""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
import pytest
import torch

from kinematics.description import load_description
from kinematics.model import RobotModel
from learner.config import ModelConfig, TrainConfig
from learner.features import feature_spec
from learner.model import ErrorModel

Labels = Callable[[np.ndarray], np.ndarray]


@pytest.fixture(scope="session")
def train_fanuc() -> Callable[[int, ModelConfig, int, Labels], tuple]:
    """A factory: the Fanuc M-900iB/700 and an :class:`ErrorModel` (seed 0, features: joints
    and one ambient temperature at 20 °C) trained for ``max_epochs`` on ``n`` seeded poses in
    half the joint range against ``labels(q)`` (m, rad); returns ``(robot, model, q)``."""

    def train(n: int, model_cfg: ModelConfig, max_epochs: int, labels: Labels) -> tuple:
        torch.set_num_threads(1)
        robot = RobotModel(load_description("fanuc_m900ib700"))
        spec = feature_spec(robot.description, 1, False, ("ambient",))
        rng = np.random.default_rng(0)
        lim = robot.description.limits_rad * 0.5
        q = rng.uniform(lim[:, 0], lim[:, 1], size=(n, 6))
        X = np.hstack([q, np.full((n, 1), 20.0)])
        model = ErrorModel.create(spec, model_cfg, TrainConfig(max_epochs=max_epochs), seed=0)
        model.fit(X, labels(q))
        return robot, model, q

    return train
