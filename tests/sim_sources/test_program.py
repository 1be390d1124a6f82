"""Measurement programs: measurable targets in the limits, balanced approaches, timing."""

import numpy as np
import pytest

from kinematics.description import load_description
from kinematics.effects import Conditions, perturbed_poses
from kinematics.errors import ConfigError
from kinematics.measurability import measurability_from_poses
from kinematics.model import RobotModel
from sim_sources.program import (
    CellConfig,
    ProgramConfig,
    Visit,
    balanced_levels,
    make_program,
    measurable,
)


@pytest.fixture(scope="module")
def fanuc() -> RobotModel:
    return RobotModel(load_description("fanuc_m900ib700"))


@pytest.fixture(scope="module")
def program(fanuc):
    config = ProgramConfig(block_points=40, load_episode_points=10)
    return make_program(fanuc, 200, np.random.default_rng(3), config)


def test_targets_are_in_the_limits_and_seen_by_the_tracker(fanuc, program):
    lim = fanuc.description.limits_rad
    for q in (program.q, program.q_pre):
        assert np.all((q >= lim[:, 0]) & (q <= lim[:, 1]))
    poses = perturbed_poses(fanuc, Conditions(q=program.q, t=program.t_measure_s), [])
    cell = CellConfig()
    vis = measurability_from_poses(cell.T_W_0()[None] @ poses)
    assert vis.visible.all() and np.all(vis.distance_m >= 1.5)
    assert np.all(vis.angle_rad <= np.deg2rad(45.0))
    assert np.all(poses[:, 2, 3] >= cell.min_height_m)


def test_every_joint_is_approached_from_both_sides_equally(program):
    assert set(np.unique(program.approach)) == {-1.0, 1.0}
    np.testing.assert_array_equal(program.approach.sum(axis=0), 0.0)
    step = program.q - program.q_pre
    np.testing.assert_allclose(np.sign(step), program.approach)


def test_visit_times_are_ordered_and_phases_heat_and_cool(program):
    t = np.stack(
        [program.t_depart_s, program.t_pre_s, program.t_arrive_s, program.t_settled_s,
         program.t_leave_s], axis=1,
    )  # fmt: skip
    assert np.all(np.diff(t, axis=1) > 0)
    assert np.all(program.t_depart_s[1:] >= program.t_leave_s[:-1])
    kinds = [p.kind for p in program.phases]
    assert {"measure", "warm_up", "cool_down"} <= set(kinds)
    assert all(
        a.end_s == b.start_s for a, b in zip(program.phases, program.phases[1:], strict=False)
    )
    warm = [p for p in program.phases if p.kind == "warm_up"][0]
    inside = (program.t_measure_s > warm.start_s) & (program.t_measure_s < warm.end_s)
    assert not inside.any() and warm.heating == 1.0


def test_loads_come_in_episodes_within_the_air_spring_range(program):
    assert program.air_spring_n.max() <= 3000.0
    episodes = program.payload_kg.reshape(-1, 10)
    assert np.all(episodes == episodes[:, :1])
    assert len(np.unique(program.air_spring_n)) > 1


def test_visits_expose_the_program_one_point_at_a_time(program):
    visits = list(program.visits())
    assert len(visits) == len(program) and isinstance(visits[5], Visit)
    np.testing.assert_array_equal(visits[5].q, program.q[5])
    assert visits[5].t_settled_s == program.t_settled_s[5]


def test_same_seed_same_program(fanuc):
    a, b = (make_program(fanuc, 20, np.random.default_rng(9)) for _ in range(2))
    np.testing.assert_array_equal(a.q, b.q)
    np.testing.assert_array_equal(a.t_leave_s, b.t_leave_s)


def test_measurable_rejects_a_probe_looking_away():
    cell = CellConfig(tracker_xyz_m=(3.0, 0.0, 1.0), tracker_yaw_deg=0.0)
    T = np.tile(np.eye(4), (2, 1, 1))
    T[:, :3, 3] = [0.0, 0.0, 1.0]
    T[0, :3, :3] = [[0, 0, 1], [0, 1, 0], [-1, 0, 0]]  # z axis towards +x: facing the tracker
    assert measurable(T, cell).tolist() == [True, False]


def test_balanced_levels_keep_the_mix():
    values = balanced_levels((0.0, 700.0), (0.9, 0.1), 30, np.random.default_rng(0))
    assert np.sum(values == 700.0) == 3


def test_bad_program_values_raise():
    with pytest.raises(ConfigError, match="air_spring_levels_n"):
        ProgramConfig(air_spring_levels_n=(0.0, 5000.0))
    with pytest.raises(ConfigError, match="n >= 1"):
        make_program(RobotModel(load_description("ur10")), 0, np.random.default_rng(0))
