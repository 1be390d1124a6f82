"""The effect family: conformance over every member, and each effect's physics."""

from dataclasses import replace

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from kinematics.description import load_description
from kinematics.effects import (
    DH_FIELDS,
    EFFECTS,
    Backlash,
    BaseFrame,
    Conditions,
    GearPeriodic,
    Geometric,
    JointCompliance,
    ThermalExpansion,
    ToolFrame,
    TrackerDrift,
    coupling_matrix,
    ctrl_to_dh_delta,
    dh_to_ctrl_delta,
    frame_correction,
    perturbed_poses,
)
from kinematics.effects.thermal_expansion import REFERENCE_SENSORS
from kinematics.errors import ConfigError
from kinematics.model import RobotModel

VOCABULARY = (
    "geometric",
    "joint_compliance",
    "thermal_expansion",
    "backlash",
    "gear_periodic",
    "tracker_drift",
    "base_frame",
    "tool_frame",
)


@pytest.fixture(scope="module")
def fanuc() -> RobotModel:
    return RobotModel(load_description("fanuc_m900ib700"))


def conditions(model: RobotModel, n: int = 64, seed: int = 0, **changes) -> Conditions:
    """Random in-limit conditions with every field filled (50 °C everywhere, +1 approach)."""
    rng = np.random.default_rng(seed)
    lim = model.description.limits_rad
    q = rng.uniform(lim[:, 0], lim[:, 1], (n, lim.shape[0]))
    cond = Conditions(
        q=q,
        t=np.linspace(0.0, 3600.0, n),
        temperatures=np.full((n, len(REFERENCE_SENSORS)), 50.0),
        temperature_names=REFERENCE_SENSORS,
        approach=np.ones_like(q),
        payload_kg=0.0,
        tool_force_n=np.zeros((n, 3)),
    )
    return replace(cond, **changes)


def test_registry_names_the_whole_vocabulary():
    assert set(EFFECTS) == set(VOCABULARY)
    assert all(cls.name == name for name, cls in EFFECTS.items())


@pytest.mark.parametrize("name", VOCABULARY)
def test_zero_parameters_leave_the_nominal_robot(fanuc, name):
    effect = EFFECTS[name]()
    cond = conditions(fanuc)
    params = effect.zero_parameters(fanuc.description)
    poses = perturbed_poses(fanuc, cond, [(effect, params)])
    assert np.abs(poses - fanuc.fk(cond.q)).max() < 1e-12


@pytest.mark.parametrize("name", VOCABULARY)
def test_parameter_names_are_unique_and_carry_units(fanuc, name):
    names = EFFECTS[name]().parameter_names(fanuc.description)
    assert len(set(names)) == len(names) > 0
    assert all(n.endswith(("_m", "_rad", "_per_K", "_rad_per_Nm", "_per_s")) for n in names)


@pytest.mark.parametrize("name", VOCABULARY)
def test_wrong_parameter_count_is_a_one_line_config_error(fanuc, name):
    with pytest.raises(ConfigError, match="expected .* parameters, got 1"):
        EFFECTS[name]().perturbation(fanuc, np.zeros(1), conditions(fanuc))


@pytest.mark.parametrize("name", [n for n in VOCABULARY if n not in ("base_frame", "tool_frame")])
def test_joint_and_dh_parts_are_linear_in_the_parameters(fanuc, name):
    effect = EFFECTS[name]()
    rng = np.random.default_rng(1)
    p = 1e-6 * rng.standard_normal(len(effect.parameter_names(fanuc.description)))
    cond = conditions(fanuc, n=16)
    one, two = effect.perturbation(fanuc, p, cond), effect.perturbation(fanuc, 2 * p, cond)
    np.testing.assert_allclose(two.dq, 2 * one.dq, atol=1e-15)
    np.testing.assert_allclose(two.ddh, 2 * one.ddh, atol=1e-15)


def test_geometric_matches_a_pinocchio_model_of_the_changed_description(fanuc):
    desc = fanuc.description
    params = np.zeros((desc.n_joints, len(DH_FIELDS)))
    params[1, 0] = 1e-3  # a2 + 1 mm
    params[2, 4] = np.deg2rad(0.05)  # offset3 + 0.05 deg
    params[3, 3] = np.deg2rad(0.02)  # beta4
    joints = list(desc.joints)
    joints[1] = replace(joints[1], a_m=joints[1].a_m + 1e-3)
    joints[2] = replace(joints[2], offset_deg=joints[2].offset_deg + 0.05)
    joints[3] = replace(joints[3], beta_deg=joints[3].beta_deg + 0.02)
    changed = RobotModel(replace(desc, joints=tuple(joints)))
    cond = conditions(fanuc)
    poses = perturbed_poses(fanuc, cond, [(Geometric(), params.reshape(-1))])
    assert np.abs(poses - changed.fk(cond.q)).max() < 1e-12


def compliance(model: RobotModel) -> np.ndarray:
    return 1.0 / np.array([3e7, 2e7, 3e7, 5e6, 4e6, 3e6])


def test_gravity_sags_the_tool(fanuc):
    cond = conditions(fanuc, n=200)
    dz = (
        perturbed_poses(fanuc, cond, [(JointCompliance(), compliance(fanuc))]) - fanuc.fk(cond.q)
    )[:, 2, 3]
    assert dz.mean() < -1e-4 and np.mean(dz < 0) > 0.9


def test_payload_adds_sag_and_a_balancer_removes_some(fanuc):
    c = compliance(fanuc)
    empty = conditions(fanuc, n=200)
    loaded = replace(empty, payload_kg=np.full(200, 700.0))
    z = {
        (name, b): perturbed_poses(fanuc, cond, [(JointCompliance(balancer=b), c)])[:, 2, 3]
        for name, cond in (("empty", empty), ("loaded", loaded))
        for b in ((), (0.0, 0.9))
    }
    extra = z["loaded", ()] - z["empty", ()]
    assert extra.mean() < -1e-4 and np.mean(extra < 0) > 0.95
    nominal_z = fanuc.fk(empty.q)[:, 2, 3]
    assert np.mean(np.abs(z["empty", (0.0, 0.9)] - nominal_z)) < np.mean(
        np.abs(z["empty", ()] - nominal_z)
    )


def test_an_air_spring_pushes_the_tool_along_its_force(fanuc):
    cond = conditions(fanuc, n=100)
    force = 3000.0 * np.tile([0.0, 0.0, 1.0], (100, 1))
    c = compliance(fanuc)
    without = perturbed_poses(fanuc, cond, [(JointCompliance(), c)])
    with_force = perturbed_poses(fanuc, replace(cond, tool_force_n=force), [(JointCompliance(), c)])
    moved = with_force[:, :3, 3] - without[:, :3, 3]
    assert np.all(np.einsum("ni,ni->n", moved, force) > 0)


def test_compliance_respects_the_parallelogram_coupling(fanuc):
    C = coupling_matrix(fanuc.description)
    assert C[2, 1] == 1.0 and C[1, 2] == 0.0
    dq = np.random.default_rng(0).standard_normal((5, 6))
    np.testing.assert_allclose(
        dh_to_ctrl_delta(fanuc.description, ctrl_to_dh_delta(fanuc.description, dq)), dq
    )


def test_heat_lengthens_the_links_so_the_reach_grows(fanuc):
    effect, k = ThermalExpansion(), np.full(6, 11.5e-6)
    cold = conditions(fanuc, temperatures=np.full((64, 15), 20.0))
    hot = conditions(fanuc, temperatures=np.full((64, 15), 55.0))
    assert np.abs(perturbed_poses(fanuc, cold, [(effect, k)]) - fanuc.fk(cold.q)).max() < 1e-12
    pert = effect.perturbation(fanuc, k, hot)
    lengths = np.array([[j.a_m, j.d_m] for j in fanuc.description.joints])
    np.testing.assert_allclose(pert.ddh[0, :, :2], lengths * 11.5e-6 * 35.0)
    q = np.zeros((1, 6))  # arm stretched out forward
    stretched = replace(
        hot,
        q=q,
        t=np.zeros(1),
        temperatures=hot.temperatures[:1],
        approach=np.ones((1, 6)),
        tool_force_n=None,
    )
    reach_hot = np.linalg.norm(perturbed_poses(fanuc, stretched, [(effect, k)])[0, :3, 3])
    assert reach_hot > np.linalg.norm(fanuc.fk(q)[0, :3, 3]) + 1e-4


def test_one_thermometer_drives_every_link(fanuc):
    k = np.full(6, 11.5e-6)
    full = conditions(fanuc, n=8)
    single = replace(full, temperatures=np.full((8, 1), 50.0), temperature_names=("hall",))
    np.testing.assert_allclose(
        perturbed_poses(fanuc, single, [(ThermalExpansion(), k)]),
        perturbed_poses(fanuc, full, [(ThermalExpansion.single("ambient"), k)]),
    )
    two = replace(full, temperatures=np.full((8, 2), 50.0), temperature_names=("a", "b"))
    with pytest.raises(ConfigError, match="link 1 needs sensor"):
        ThermalExpansion().perturbation(fanuc, k, two)


def test_backlash_flips_sign_with_the_approach(fanuc):
    h = np.full(6, np.deg2rad(1.0 / 60.0))
    up = conditions(fanuc, n=32)
    down = replace(up, approach=-up.approach)
    a, b = Backlash().perturbation(fanuc, h, up), Backlash().perturbation(fanuc, h, down)
    np.testing.assert_allclose(a.dq, -b.dq)
    assert np.all(a.dq[:, 0] < 0)  # the link lags the motor that moved it forward
    p_up, p_down = (perturbed_poses(fanuc, c, [(Backlash(), h)]) for c in (up, down))
    nominal = fanuc.fk(up.q)
    np.testing.assert_allclose(
        p_up[:, :3, 3] - nominal[:, :3, 3], -(p_down[:, :3, 3] - nominal[:, :3, 3]), atol=1e-5
    )
    with pytest.raises(ConfigError, match="needs conditions.approach"):
        Backlash().perturbation(fanuc, h, replace(up, approach=None))


def test_backlash_by_torque_sign_follows_the_load(fanuc):
    h = np.full(6, 1e-4)
    cond = conditions(fanuc, n=32)
    dq = Backlash(sign_from="torque").perturbation(fanuc, h, cond).dq
    compl = JointCompliance().perturbation(fanuc, np.full(6, 1e-8), cond).dq
    big = np.abs(compl[:, 1]) > 1e-7
    assert np.all(np.sign(dq[big, 1]) == np.sign(compl[big, 1]))


def test_gear_errors_are_periodic_in_the_joint_angle(fanuc):
    effect = GearPeriodic(orders=(1, 2))
    p = 1e-5 * np.random.default_rng(2).standard_normal(24)
    cond = conditions(fanuc, n=16)
    turned = replace(cond, q=cond.q + 2 * np.pi)
    np.testing.assert_allclose(
        effect.perturbation(fanuc, p, cond).dq, effect.perturbation(fanuc, p, turned).dq, atol=1e-15
    )
    only_j1_sin = np.zeros(24)
    only_j1_sin[0] = 1e-4
    dq = effect.perturbation(fanuc, only_j1_sin, cond).dq
    np.testing.assert_allclose(dq[:, 0], 1e-4 * np.sin(cond.q[:, 0]))


def test_tracker_drift_grows_with_time(fanuc):
    params = np.array([1e-9, -2e-9, 3e-9, 1e-10, 0.0, -1e-10])
    same_q = np.repeat(conditions(fanuc, n=1).q, 3, axis=0)
    cond = conditions(fanuc, n=3, q=same_q, t=np.array([0.0, 3600.0, 7200.0]))
    err = perturbed_poses(fanuc, cond, [(TrackerDrift(), params)]) - fanuc.fk(cond.q)
    shift = np.linalg.norm(err[:, :3, :3], axis=(1, 2)) + np.linalg.norm(err[:, :3, 3], axis=1)
    assert shift[0] < 1e-12 and 1e-6 < shift[1] < shift[2]
    translation_only = perturbed_poses(fanuc, cond, [(TrackerDrift(), np.r_[params[:3], 0, 0, 0])])
    moved = translation_only[:, :3, 3] - fanuc.fk(cond.q)[:, :3, 3]
    np.testing.assert_allclose(moved[2], 2 * moved[1], rtol=1e-9)


def test_frame_errors_act_left_and_right(fanuc):
    cond = conditions(fanuc, n=8)
    base = np.array([1e-3, 0, 0, 0, 0, 1e-3])
    tool = np.array([0, 2e-3, 0, 1e-3, 0, 0])
    poses = perturbed_poses(fanuc, cond, [(BaseFrame(), base), (ToolFrame(), tool)])
    expected = (
        frame_correction(base[:3], base[3:])[None]
        @ fanuc.fk(cond.q)
        @ frame_correction(tool[:3], tool[3:])[None]
    )
    np.testing.assert_allclose(poses, expected, atol=1e-14)


@pytest.mark.parametrize(
    "effect",
    [
        JointCompliance(balancer=(0.0, 0.9)),
        Backlash(sign_from="torque"),
        GearPeriodic(orders=(1, 3)),
        ThermalExpansion.single("ambient", t_ref_c=22.0),
    ],
)
def test_options_rebuild_the_same_effect(effect):
    assert type(effect)(**effect.options()).options() == effect.options()


@pytest.mark.parametrize(
    "build, message",
    [
        (lambda: Backlash(sign_from="speed"), "sign_from must be one of"),
        (lambda: GearPeriodic(orders=(0,)), "orders must be positive integers"),
        (lambda: JointCompliance(balancer=(1.5,)), "balancer must be in"),
        (lambda: ThermalExpansion(t_ref_c=float("nan")), "t_ref_c must be finite"),
    ],
)
def test_bad_options_raise_one_line(build, message):
    with pytest.raises(ConfigError, match=message):
        build()


#: Typical parameter sizes per effect, for random but physically sized parameters.
TYPICAL = {
    "geometric": 1e-4,
    "joint_compliance": 5e-8,
    "thermal_expansion": 1e-5,
    "backlash": 1e-4,
    "gear_periodic": 5e-5,
    "tracker_drift": 1e-9,
    "base_frame": 1e-3,
    "tool_frame": 1e-3,
}


@settings(max_examples=20, deadline=None)
@given(seed=st.integers(0, 2**31), scale=st.floats(0.0, 10.0))
def test_all_effects_together_give_rigid_poses(fanuc, seed, scale):
    rng = np.random.default_rng(seed)
    desc = fanuc.description
    effects = []
    for name, size in TYPICAL.items():
        effect = EFFECTS[name]()
        k = len(effect.parameter_names(desc))
        effects.append((effect, scale * size * np.abs(rng.standard_normal(k))))
    poses = perturbed_poses(fanuc, conditions(fanuc, n=8, seed=seed % 1000), effects)
    R = poses[:, :3, :3]
    np.testing.assert_allclose(
        R @ np.swapaxes(R, 1, 2), np.broadcast_to(np.eye(3), R.shape), atol=1e-12
    )
    np.testing.assert_allclose(poses[:, 3], np.broadcast_to([0, 0, 0, 1.0], (8, 4)))


@pytest.mark.parametrize("name", VOCABULARY)
def test_poses_are_smooth_in_the_parameters(fanuc, name):
    """Central differences at two step sizes agree: what the identification's Jacobian needs."""
    effect = EFFECTS[name]()
    desc = fanuc.description
    k = len(effect.parameter_names(desc))
    p0 = TYPICAL[name] * np.random.default_rng(4).standard_normal(k)
    cond = conditions(fanuc, n=6)

    def derivative(h: float) -> np.ndarray:
        cols = []
        for j in range(k):
            dp = np.zeros(k)
            dp[j] = h
            plus = perturbed_poses(fanuc, cond, [(effect, p0 + dp)])[:, :3, 3]
            minus = perturbed_poses(fanuc, cond, [(effect, p0 - dp)])[:, :3, 3]
            cols.append((plus - minus) / (2 * h))
        return np.stack(cols, axis=-1)

    h = TYPICAL[name] * 1e-2
    coarse, fine = derivative(h), derivative(h / 4)
    np.testing.assert_allclose(coarse, fine, rtol=1e-4, atol=1e-6 * np.abs(fine).max())


def test_inconsistent_conditions_raise_one_line(fanuc):
    cond = conditions(fanuc, n=4)
    with pytest.raises(ConfigError, match=r"conditions.t must have shape \(4,\), got \(3,\)"):
        replace(cond, t=np.zeros(3))
    with pytest.raises(ConfigError, match="conditions.temperatures must have shape"):
        replace(cond, temperature_names=("ambient",))
    with pytest.raises(ConfigError, match="payload_kg must be a scalar or"):
        replace(cond, payload_kg=np.zeros(3))
