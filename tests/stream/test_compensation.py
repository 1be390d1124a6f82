"""Compensation maths with a real trained error model and the pinocchio Jacobian."""

from dataclasses import replace

import numpy as np
import pytest

from kinematics.description import load_description
from kinematics.model import RobotModel
from kinematics.transforms import apply_error, pose_error, xyz_quat_from_transform
from learner.config import ModelConfig, TrainConfig
from learner.features import feature_spec
from learner.model import ErrorModel
from stream.compensation import (
    CompensationConfig,
    CompensationRequest,
    compensate,
    controller_jacobian,
    request_features,
)
from wire import RejectedMessageError, decode, encode


def true_error(q: np.ndarray) -> np.ndarray:
    """A smooth pose error (m, rad) the model learns: millimetres, arcminutes."""
    q = np.atleast_2d(q)
    return np.stack(
        [
            2e-3 * np.sin(q[:, 0]),
            1.5e-3 * np.cos(q[:, 1]),
            1e-3 + 5e-4 * q[:, 2],
            2e-4 * np.sin(q[:, 3]),
            -1e-4 * np.ones(len(q)),
            1e-4 * q[:, 4],
        ],
        axis=1,
    )


@pytest.fixture(scope="module")
def fanuc(train_fanuc):
    return train_fanuc(200, ModelConfig(hidden_layers=2, neurons=32), 150, true_error)


def test_controller_jacobian_matches_finite_differences():
    robot = RobotModel(load_description("fanuc_m900ib700"))
    q = np.array([0.3, 0.2, -0.4, 0.5, 0.6, -0.2])
    J = controller_jacobian(robot, q)
    h = 1e-6
    for i in range(6):
        dq = np.zeros(6)
        dq[i] = h
        num = pose_error(robot.fk(q + dq), robot.fk(q - dq))[0] / (2 * h)
        np.testing.assert_allclose(J[:, i], num, atol=1e-5)


def test_corrected_commands_land_on_the_target(fanuc):
    robot, model, q_train = fanuc
    cfg = CompensationConfig(epistemic_limit_mm=5.0)
    before, after, residuals = [], [], []
    for q in q_train[:20] * 0.9:
        target = robot.fk(q[None])
        req = CompensationRequest(q=tuple(q), temperatures={"ambient": 20.0})
        reply = compensate(model, robot, req, cfg, model_version=3)
        qc = np.array(reply.q_corrected)
        true_at = apply_error(robot.fk(qc[None]), true_error(qc))
        before.append(np.linalg.norm(true_error(q)[0, :3]))
        after.append(np.linalg.norm(pose_error(true_at, target)[0, :3]))
        residuals.append(reply.residual_m)
        assert reply.model_version == 3
        lo, hi, e = map(np.array, (reply.lo, reply.hi, reply.error))
        assert np.all(lo < e) and np.all(e < hi)
    assert np.mean(after) < 0.3 * np.mean(before)
    # converged (< 1 µm) except near a singular wrist, where the damped step stops short
    assert np.mean(np.array(residuals) < 1e-6) >= 0.9 and max(residuals) < 2e-4


def test_target_pose_request_matches_joint_request(fanuc):
    robot, model, q_train = fanuc
    q = q_train[0] * 0.9
    xyz, quat = xyz_quat_from_transform(robot.fk(q[None]))
    cfg = CompensationConfig()
    by_q = compensate(
        model, robot, CompensationRequest(q=tuple(q), temperatures={"ambient": 20}), cfg
    )
    by_pose = compensate(
        model,
        robot,
        CompensationRequest(
            q=tuple(q),
            target_xyz=tuple(xyz[0]),
            target_quat=tuple(quat[0]),
            temperatures={"ambient": 20.0},
        ),
        cfg,
    )
    np.testing.assert_allclose(by_q.q_corrected, by_pose.q_corrected, atol=1e-8)


def test_far_from_the_data_is_untrusted(fanuc):
    robot, model, q_train = fanuc
    cfg = CompensationConfig(epistemic_limit_mm=1e-4)
    reply = compensate(
        model, robot, CompensationRequest(q=tuple(q_train[0]), temperatures={"ambient": 20.0}), cfg
    )
    assert not reply.trusted and "epistemic" in reply.reason


def test_request_validation_and_features():
    spec = feature_spec(load_description("ur10"), 1, True, ("ambient",))
    model = ErrorModel.create(spec, ModelConfig(hidden_layers=1, neurons=4), TrainConfig(), 0)
    q = np.arange(6) / 10
    req = CompensationRequest(q=(0.0,) * 6, deflection=(1e-4,) + (0.0,) * 5, temperatures={})
    X = request_features(model, replace(req, temperatures={"ambient": 21}), q)
    assert X.tolist() == [[*q, 1e-4, *[0.0] * 5, 21.0]]  # exactly: no arithmetic on the way
    X = request_features(model, replace(req, deflection=None, temperatures={"temp_ambient": 9}), q)
    assert X[0, 6:].tolist() == [0.0] * 6 + [9.0]  # no deflection reads zero
    with pytest.raises(RejectedMessageError, match="temp_ambient") as err:
        request_features(model, req, q)
    assert err.value.reason == "malformed"
    good = CompensationRequest(q=(0.0,) * 6, temperatures={"a": 20.0})
    assert decode(encode(good), CompensationRequest) == good
    bad = encode(good).replace(b'"target_xyz":null', b'"target_xyz":[1,2,3]')
    with pytest.raises(RejectedMessageError, match="target"):
        decode(bad, CompensationRequest)
