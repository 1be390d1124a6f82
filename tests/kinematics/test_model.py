"""The pinocchio model against an independent product of DH-Hayati matrices; gravity torques."""

from dataclasses import replace

import numpy as np
import pytest

from kinematics.description import load_description
from kinematics.model import RobotModel

ROBOTS = ("ur10", "fanuc_m900ib700")


def elementary(axis: str, kind: str, value) -> np.ndarray:
    """Batched ``(N, 4, 4)`` rotation (``"R"``, rad) or translation (``"T"``, m) on ``axis``."""
    value = np.atleast_1d(np.asarray(value, dtype=float))
    T = np.broadcast_to(np.eye(4), (value.size, 4, 4)).copy()
    i = "xyz".index(axis)
    if kind == "T":
        T[:, i, 3] = value
        return T
    a, b = [k for k in range(3) if k != i]
    if axis == "y":
        a, b = b, a  # Ry: [[c, 0, s], [0, 1, 0], [-s, 0, c]]
    c, s = np.cos(value), np.sin(value)
    T[:, a, a], T[:, a, b], T[:, b, a], T[:, b, b] = c, -s, s, c
    return T


def dh_product(q_dh: np.ndarray, desc) -> np.ndarray:
    """``prod_i Rz(q_i + offset_i) Tx(a_i) Tz(d_i) Rx(alpha_i) Ry(beta_i)`` for ``(N, n)``."""
    T = np.broadcast_to(np.eye(4), (len(q_dh), 4, 4))
    for qi, j in zip(q_dh.T, desc.joints, strict=True):
        T = (
            T
            @ elementary("z", "R", qi + np.deg2rad(j.offset_deg))
            @ elementary("x", "T", j.a_m)
            @ elementary("z", "T", j.d_m)
            @ elementary("x", "R", np.deg2rad(j.alpha_deg))
            @ elementary("y", "R", np.deg2rad(j.beta_deg))
        )
    return T


def test_elementary_rotations_are_right_handed():
    # A +90 deg turn takes x to y about z, y to z about x, z to x about y.
    e = np.eye(4)
    np.testing.assert_allclose(elementary("z", "R", np.pi / 2)[0] @ e[0], e[1], atol=1e-15)
    np.testing.assert_allclose(elementary("x", "R", np.pi / 2)[0] @ e[1], e[2], atol=1e-15)
    np.testing.assert_allclose(elementary("y", "R", np.pi / 2)[0] @ e[2], e[0], atol=1e-15)


def random_q(desc, n: int, seed: int = 0) -> np.ndarray:
    lim = desc.limits_rad
    return np.random.default_rng(seed).uniform(lim[:, 0], lim[:, 1], (n, desc.n_joints))


@pytest.mark.parametrize("robot", ROBOTS)
def test_fk_matches_independent_dh_product(robot):
    desc = load_description(robot)
    q = random_q(desc, 10_000)
    q_dh = q.copy()
    if desc.coupling == "j3_plus_j2":
        q_dh[:, 2] += q[:, 1]
    ref = dh_product(q_dh, desc)
    model = RobotModel(desc)
    np.testing.assert_allclose(model.fk(q, frame="flange"), ref, rtol=0, atol=1e-9)
    np.testing.assert_allclose(model.fk(q), ref @ desc.tool[None], rtol=0, atol=1e-9)


def test_fanuc_coupling_is_exercised():
    desc = load_description("fanuc_m900ib700")
    q = random_q(desc, 200, seed=1)
    coupled = RobotModel(desc).fk(q, frame="flange")
    uncoupled = dh_product(q, desc)
    # Without q3_dh = q3 + q2 the positions would be far off (metres for this arm).
    assert np.median(np.linalg.norm(coupled[:, :3, 3] - uncoupled[:, :3, 3], axis=1)) > 0.1
    np.testing.assert_allclose(desc.to_dh(q)[:, 2], q[:, 2] + q[:, 1])


def test_beta_and_offset_are_used():
    base = load_description("ur10")
    joints = list(base.joints)
    joints[1] = replace(joints[1], beta_deg=0.5, offset_deg=3.0)
    desc = replace(base, joints=tuple(joints))
    q = random_q(desc, 50)
    np.testing.assert_allclose(
        RobotModel(desc).fk(q, frame="flange"), dh_product(q, desc), rtol=0, atol=1e-9
    )
    assert np.abs(RobotModel(base).fk(q) - RobotModel(desc).fk(q)).max() > 1e-3


def test_payload_increases_shoulder_torque():
    model = RobotModel(load_description("fanuc_m900ib700"))
    q = np.array([[0.0, 0.3, -0.2, 0.0, -0.5, 0.0]])
    empty = model.gravity_torque(q)
    loaded = model.gravity_torque(q, payload_kg=700.0, payload_com_m=(0.0, 0.0, 0.3))
    assert abs(loaded[0, 1]) > abs(empty[0, 1]) + 700 * 9.81 * 1.0  # lever > 1 m
    assert np.all(np.isfinite(loaded))


@pytest.mark.parametrize("robot", ROBOTS)
def test_no_gravity_torque_about_the_vertical_first_axis(robot):
    desc = load_description(robot)
    q = random_q(desc, 100, seed=2)
    tau = RobotModel(desc).gravity_torque(q, payload_kg=50.0)
    assert np.abs(tau[:, 0]).max() < 1e-9
    assert np.abs(tau[:, 1]).max() > 1.0


def test_tool_force_enters_through_the_jacobian():
    model = RobotModel(load_description("fanuc_m900ib700"))
    q = np.array([[0.0, 0.2, -0.1, 0.0, -0.4, 0.0]])
    force = np.array([[0.0, 0.0, 3000.0]])  # an air spring pushing up
    delta = model.gravity_torque(q, tool_force_n=force) - model.gravity_torque(q)
    J = model.jacobian(q)[0]
    np.testing.assert_allclose(delta[0], -J[:3].T @ force[0], atol=1e-9)


def test_jacobian_matches_finite_differences():
    desc = load_description("ur10")
    model = RobotModel(desc)
    q = random_q(desc, 1, seed=3)
    J = model.jacobian(q)[0]
    h = 1e-7
    for i in range(6):
        dq = np.zeros(6)
        dq[i] = h
        dp = (model.fk(q + dq)[0, :3, 3] - model.fk(q - dq)[0, :3, 3]) / (2 * h)
        np.testing.assert_allclose(J[:3, i], dp, atol=1e-6)


@pytest.mark.parametrize("robot", ROBOTS)
def test_batched_sensor_jacobians_match_pinocchio(robot):
    from kinematics.effects import coupling_matrix, sensor_jacobians

    tool = np.array([[1, 0, 0, 0.1], [0, 1, 0, 0.05], [0, 0, 1, 0.35], [0, 0, 0, 1.0]])
    desc = load_description(robot).with_tool(tool)
    model = RobotModel(desc)
    poses_and_jacobians = sensor_jacobians(desc)
    for n in (1, 4, 5, 200):  # pinocchio's loop answers few poses, a numpy batch many
        q = random_q(desc, n, seed=5)
        T, J = poses_and_jacobians(q)
        assert np.abs(T - model.fk(q)).max() < 1e-12
        assert np.abs(J - model.jacobian(q) @ coupling_matrix(desc)).max() < 1e-12
