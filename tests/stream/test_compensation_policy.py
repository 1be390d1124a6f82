"""Compensation policy near a singular wrist: refuse, flag or best effort within a joint-motion
limit; every reply names the policy that applied and the solver residual."""

import time

import numpy as np
import pytest

from kinematics.errors import ConfigError
from learner.config import ModelConfig
from learner.snapshot import snapshot_to_bytes
from stream.bus import BusConfig, free_port, open_session
from stream.compensation import CompensationConfig, CompensationReply, CompensationRequest
from stream.compensation_guard import GuardConfig, guarded_compensate
from stream.stages.compensation_service import CompensationService
from tests.stream.conftest import wait_subscribed
from wire import ModelHeader, decode, encode, encode_model, key

# q5 = 1 mrad: the wrist is nearly singular (smallest singular value of the controller
# Jacobian 5e-4); landing takes about 0.1 rad of wrist motion, five capped steps give 0.05 rad
NEAR_SINGULAR = (0.3, 0.2, -0.3, 0.4, 1e-3, 0.2)
REGULAR = (0.3, 0.2, -0.3, 0.4, 0.8, 0.2)
LIMIT_M = GuardConfig().max_residual_m


@pytest.fixture(scope="module")
def fanuc(train_fanuc):
    robot, model, _ = train_fanuc(
        100, ModelConfig(hidden_layers=1, neurons=16), 20, lambda q: 2e-3 * np.sin(q)
    )
    return robot, model


def answer(fanuc, q, **cfg) -> CompensationReply:
    """The reply through the wire codec, as the service sends it; few iterations so the
    near-singular command cannot land without a policy."""
    robot, model = fanuc
    config = CompensationConfig(max_iterations=5, epistemic_limit_mm=100.0, **cfg)
    req = CompensationRequest(q=q, temperatures={"ambient": 20.0})
    reply = guarded_compensate(model, robot, req, config, 3)
    return decode(encode(reply), CompensationReply)


def test_a_command_that_lands_needs_no_policy(fanuc):
    for policy in ("refuse", "flag", "best_effort"):
        reply = answer(fanuc, REGULAR, policy=policy)
        assert reply.trusted and reply.policy == "none" and reply.reason == ""
        assert reply.residual_m <= LIMIT_M and 0 < reply.joint_motion_rad < 0.01


def test_refuse_answers_the_uncorrected_command(fanuc):
    reply = answer(fanuc, NEAR_SINGULAR, policy="refuse")
    assert not reply.trusted and reply.policy == "refuse"
    assert reply.q_corrected == NEAR_SINGULAR and reply.joint_motion_rad == 0.0
    assert reply.reason.startswith("residual: solver ") and "policy refuse" in reply.reason
    # the residual of the answered (uncorrected) command: the whole predicted position error
    assert reply.residual_m == pytest.approx(np.linalg.norm(reply.error[:3]), rel=1e-2)


def test_flag_answers_the_partial_correction(fanuc):
    reply = answer(fanuc, NEAR_SINGULAR, policy="flag")
    assert not reply.trusted and reply.policy == "flag"
    assert reply.residual_m > LIMIT_M and reply.q_corrected != NEAR_SINGULAR
    assert reply.joint_motion_rad <= 5 * 0.01 + 1e-12  # five steps of at most 0.01 rad
    solver_mm = float(reply.reason.split("solver ")[1].split(" mm")[0])
    assert solver_mm == pytest.approx(reply.residual_m * 1e3, abs=1e-3)


def test_best_effort_lands_within_its_joint_motion_limit(fanuc):
    reply = answer(fanuc, NEAR_SINGULAR, policy="best_effort", joint_motion_limit_rad=0.5)
    assert reply.trusted and reply.policy == "best_effort" and reply.reason == ""
    assert reply.residual_m <= LIMIT_M
    assert 0.05 < reply.joint_motion_rad <= 0.5
    motion = np.abs(np.subtract(reply.q_corrected, NEAR_SINGULAR)).max()
    assert motion == pytest.approx(reply.joint_motion_rad)


def test_best_effort_that_cannot_land_within_the_limit_is_flagged(fanuc):
    # a millimetre at a 2.5 m lever takes 4e-4 rad: 1e-5 rad cannot land it
    reply = answer(fanuc, NEAR_SINGULAR, policy="best_effort", joint_motion_limit_rad=1e-5)
    assert not reply.trusted and reply.policy == "best_effort"
    assert reply.residual_m > LIMIT_M and reply.joint_motion_rad <= 1e-5 + 1e-12
    assert reply.reason.startswith("residual: ") and "after best effort within 1e-05 rad" in (
        reply.reason
    )


def test_bad_policy_settings_are_one_line_errors():
    with pytest.raises(ConfigError, match="compensation.policy must be one of"):
        CompensationConfig(policy="ignore")
    with pytest.raises(ConfigError, match="joint_motion_limit_rad"):
        CompensationConfig(joint_motion_limit_rad=0.0)


@pytest.mark.integration
def test_the_service_answers_with_its_configured_policy(fanuc):
    """A real CompensationService on loopback Zenoh, its policy from the config."""
    robot, model = fanuc
    name, cell, port = robot.description.name, "policy", free_port()
    server = open_session(BusConfig.loopback(port, listen=True))
    client = open_session(BusConfig.loopback(port, listen=False))
    cfg = CompensationConfig(max_iterations=5, epistemic_limit_mm=100.0, policy="best_effort")
    service = CompensationService(server, cell, name, robot, cfg)
    try:
        wait_subscribed(client, key(cell, name, "model"))
        header = ModelHeader(model_version=1, robot=name, n_seen=100, t=1.0)
        client.put(key(cell, name, "model"), encode_model(header, snapshot_to_bytes(model)))
        deadline = time.monotonic() + 30.0
        while service.version < 1 and time.monotonic() < deadline:
            time.sleep(0.1)
        assert service.version == 1
        req = CompensationRequest(q=NEAR_SINGULAR, temperatures={"ambient": 20.0})
        got = list(client.get(key(cell, name, "compensate"), payload=encode(req), timeout=30.0))
        reply = decode(got[0].ok.payload.to_bytes(), CompensationReply)
        assert reply.policy == "best_effort" and reply.trusted and reply.residual_m <= LIMIT_M
        assert reply.model_version == 1 and reply.joint_motion_rad > 0.05
        # the snapshot on the bus carries the angles the model was trained on (half of each
        # joint's range): a command past them is corrected but not trusted
        req = CompensationRequest(q=(2.5, *REGULAR[1:]), temperatures={"ambient": 20.0})
        got = list(client.get(key(cell, name, "compensate"), payload=encode(req), timeout=30.0))
        reply = decode(got[0].ok.payload.to_bytes(), CompensationReply)
        assert not reply.trusted and reply.reason.startswith("envelope: q1 = 143.2 deg")
    finally:
        service.unsubscribe()
        service.close(timeout_s=10.0)
        client.close()
        server.close()
