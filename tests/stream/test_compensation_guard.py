"""Compensation refuses what it cannot do: out-of-limit joints, unreachable targets, degenerate
quaternions and misses all give ``trusted: false`` with a coded reason, never an exception."""

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from kinematics.transforms import xyz_quat_from_transform
from learner.config import ModelConfig
from learner.envelope import MARGIN_DEG
from learner.metrics import past_envelope
from stream.compensation import CompensationConfig, CompensationRequest
from stream.compensation_guard import GuardConfig, guarded_compensate, reach_m
from wire import RejectedMessageError, decode, encode

CODES = (
    "joint_limits",
    "quaternion",
    "unreachable",
    "solver",
    "residual",
    "corrected_limits",
    "epistemic",
    "envelope",
    "unverified",
)


@pytest.fixture(scope="module")
def fanuc(train_fanuc):
    robot, model, _ = train_fanuc(
        100, ModelConfig(hidden_layers=1, neurons=16), 20, lambda q: 1e-3 * np.sin(q)
    )
    return robot, model


#: What the guard answers with unless a test says otherwise.
CFG = CompensationConfig(max_iterations=10)


def answer(fanuc, cfg=CFG, **kw):
    """A request through the wire codec, then the guard (what the service does)."""
    robot, model = fanuc
    req = decode(
        encode(CompensationRequest(temperatures={"ambient": 20.0}, **kw)), CompensationRequest
    )
    return guarded_compensate(model, robot, req, cfg, 7)


def refused(reply) -> str:
    assert reply.trusted is False and reply.reason, reply
    code = reply.reason.split(":", 1)[0]
    assert code in CODES, reply.reason
    assert all(np.isfinite(v) for v in (*reply.error, *reply.q_corrected, reply.residual_m))
    return code


@settings(max_examples=40, deadline=None)
@given(
    joint=st.integers(0, 5),
    beyond_deg=st.floats(0.5, 300.0),
    above=st.booleans(),
)
def test_joints_outside_the_description_limits_are_never_trusted(fanuc, joint, beyond_deg, above):
    robot, _ = fanuc
    lim = robot.description.limits_rad
    q = np.zeros(6)
    edge = lim[joint, 1] if above else lim[joint, 0]
    q[joint] = edge + np.deg2rad(beyond_deg) * (1 if above else -1)
    if abs(q[joint]) > 4 * np.pi:  # beyond the wire's own bound: an error reply, named
        with pytest.raises(RejectedMessageError, match="out_of_range"):
            answer(fanuc, q=tuple(q))
        return
    assert refused(answer(fanuc, q=tuple(q))) == "joint_limits"


def test_all_joints_at_12_rad_is_refused_not_corrected(fanuc):
    reply = answer(fanuc, q=(12.0,) * 6)
    assert refused(reply) == "joint_limits" and reply.q_corrected == (12.0,) * 6


@pytest.mark.parametrize("distance", [5.0, 50.0, 99.0])
def test_unreachable_targets_are_refused(fanuc, distance):
    robot, _ = fanuc
    assert reach_m(robot) < 5.0
    reply = answer(
        fanuc, q=(0.0,) * 6, target_xyz=(distance, 0.0, 0.0), target_quat=(0.0, 0.0, 0.0, 1.0)
    )
    assert refused(reply) == "unreachable"


def test_a_reachable_but_missed_target_is_refused_by_its_residual(fanuc):
    robot, _ = fanuc
    T = robot.fk(np.array([[0.0, 0.2, -0.3, 0.0, 0.5, 0.0]]))[0]
    xyz, quat = xyz_quat_from_transform(T)
    far = xyz[0] + np.array([0.0, 0.0, -1.5])  # inside the reach sphere, out of the workspace
    reply = answer(fanuc, q=(0.0,) * 6, target_xyz=tuple(far), target_quat=tuple(quat[0]))
    assert refused(reply) in ("residual", "corrected_limits")


@pytest.mark.parametrize(
    "quat",
    [(0.0, 0.0, 0.0, 0.0), (1e-9, 0.0, 0.0, 0.0), (0.5, 0.0, 0.0, 0.0), (0.7, 0.7, 0.0, 0.7)],
)
def test_degenerate_quaternions_are_refused(fanuc, quat):
    reply = answer(fanuc, q=(0.0,) * 6, target_xyz=(1.5, 0.0, 1.5), target_quat=quat)
    assert refused(reply) == "quaternion"


@settings(max_examples=60, deadline=None)
@given(
    q=st.lists(st.floats(-4 * np.pi, 4 * np.pi), min_size=6, max_size=6),
    xyz=st.none() | st.lists(st.floats(-100, 100), min_size=3, max_size=3),
    quat=st.lists(st.floats(-1.0, 1.0), min_size=4, max_size=4),
)
def test_any_request_gets_an_answer_or_a_named_reason(fanuc, q, xyz, quat):
    kw = {"q": tuple(q)}
    if xyz is not None:
        kw |= {"target_xyz": tuple(xyz), "target_quat": tuple(quat)}
    try:
        reply = answer(fanuc, **kw)
    except RejectedMessageError as exc:
        assert exc.reason in ("out_of_range", "non_finite", "malformed")
        return
    if not reply.trusted:
        refused(reply)
    else:  # trusted only inside the limits and on target
        robot, _ = fanuc
        lim = robot.description.limits_rad
        assert np.all((lim[:, 0] <= reply.q_corrected) & (reply.q_corrected <= lim[:, 1]))
        assert reply.residual_m <= GuardConfig().max_residual_m
        assert not past_envelope(fanuc[1], np.array([[*q, 20.0]]), MARGIN_DEG)[0]


@pytest.mark.parametrize("joint", [0, 4])
def test_a_joint_past_the_angles_trained_on_is_not_trusted(fanuc, joint):
    """The model saw each joint in half its range only: a command beyond it, inside the
    description's limits, gets the correction but ``envelope``, naming the joint and the arc."""
    robot, _ = fanuc
    cfg = CompensationConfig(max_iterations=10, epistemic_limit_mm=1e3)  # this flag alone
    upper = robot.description.limits_rad[joint, 1]
    q = np.zeros(6)
    assert answer(fanuc, cfg, q=tuple(q)).trusted
    q[joint] = 0.8 * upper  # the training poses reach 0.5 x the limit
    reply = answer(fanuc, cfg, q=tuple(q))
    assert refused(reply) == "envelope"
    assert reply.reason.startswith(f"envelope: q{joint + 1} = {np.rad2deg(q[joint]):.1f} deg")
    assert "outside the angles trained on" in reply.reason
    assert reply.q_corrected != tuple(q)  # corrected all the same: the flag is the warning
    q[joint] = 0.5 * upper + np.deg2rad(2.0)  # within the margin
    assert answer(fanuc, cfg, q=tuple(q)).trusted
    q[joint] = 0.0
    q[5] = 0.8 * robot.description.limits_rad[5, 1]  # J6 (±360°) was trained over a whole turn
    assert answer(fanuc, cfg, q=tuple(q)).trusted


def test_a_temperature_past_the_readings_trained_on_is_not_trusted(fanuc):
    """Trained at 20 °C only: a command at 20.6 °C gets the correction but ``envelope``, naming the
    thermometer and the readings; within ``envelope_margin_k`` it is trusted."""
    robot, model = fanuc
    cfg = CompensationConfig(max_iterations=10, epistemic_limit_mm=1e3)  # this flag alone

    def at(celsius: float):
        req = CompensationRequest(q=(0.0,) * 6, temperatures={"ambient": celsius})
        return guarded_compensate(model, robot, req, cfg, 7)

    assert at(20.0).trusted and at(20.4).trusted and at(19.6).trusted
    reply = at(20.6)
    assert refused(reply) == "envelope"
    assert reply.reason == (
        "envelope: temp_ambient = 20.6 degC is more than 0.5 K outside the temperatures trained "
        "on (20.0..20.0 degC)"
    )
    assert reply.q_corrected != (0.0,) * 6  # corrected all the same: the flag is the warning
    wider = CompensationConfig(max_iterations=10, epistemic_limit_mm=1e3, envelope_margin_k=3.0)
    assert guarded_compensate(
        model, robot, CompensationRequest(q=(0.0,) * 6, temperatures={"ambient": 22.0}), wider, 7
    ).trusted


def test_a_model_whose_intervals_the_day_has_not_checked_is_not_trusted(fanuc):
    """A carry that took the frames as moved marks the model ``unverified``: every answer gets
    the correction but ``unverified``, with the carry's words, until the day has checked it."""
    robot, model = fanuc
    cfg = CompensationConfig(max_iterations=10, epistemic_limit_mm=1e3)  # this flag alone
    req = CompensationRequest(q=(0.0,) * 6, temperatures={"ambient": 20.0})
    assert guarded_compensate(model, robot, req, cfg, 7).trusted
    model.unverified = "the frames moved on this day (30 points)"
    try:
        reply = guarded_compensate(model, robot, req, cfg, 7)
    finally:
        model.unverified = ""
    assert refused(reply) == "unverified"
    assert reply.reason == "unverified: the frames moved on this day (30 points)"
    assert reply.q_corrected != (0.0,) * 6
