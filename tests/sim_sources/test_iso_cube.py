"""The ISO 9283 cube program: five reachable, measurable poses repeated for n cycles."""

import numpy as np
import pytest

from kinematics.description import load_description
from kinematics.errors import ConfigError
from kinematics.iso9283 import cube_test_positions
from kinematics.model import RobotModel
from kinematics.transforms import pose_error
from sim_sources.iso_cube import CYCLE_ORDER, find_cube, make_cube_program
from sim_sources.program import CellConfig, ProgramConfig, make_program, measurable
from sim_sources.scenarios import list_scenarios
from sim_sources.unseen import random_robot


def _check_cube(model: RobotModel, cube) -> np.ndarray:
    lim = model.description.limits_rad
    q = np.array([cube.q[k] for k in ("P1", "P2", "P3", "P4", "P5")])
    assert np.all((q >= lim[:, 0]) & (q <= lim[:, 1]))
    T = model.fk(q)
    expected = cube_test_positions(cube.centre_m, cube.edge_m)
    for k, name in enumerate(("P1", "P2", "P3", "P4", "P5")):
        assert np.allclose(T[k, :3, 3], expected[name], atol=1e-6)
    return T


def test_fanuc_cube_program_repeats_five_reachable_poses():
    model = RobotModel(load_description("fanuc_m900ib700"))
    config = ProgramConfig(kind="iso9283")
    program = make_cube_program(model, 15, config, CellConfig())
    assert len(program) == 15
    info = program.info
    assert info["kind"] == "iso9283" and info["cube_edge_m"] > 0.2
    for k, name in enumerate(CYCLE_ORDER * 3):  # P1, P5, P4, P3, P2 each cycle
        assert np.array_equal(program.q[k], np.asarray(info["q"][name]))
    # every visit approached from the same side, back-off inside the limits
    assert np.all(program.approach == 1.0)
    assert np.allclose(program.q - program.q_pre, config.approach_rad)
    lim = model.description.limits_rad
    assert np.all((program.q_pre >= lim[:, 0]) & (program.q_pre <= lim[:, 1]))
    T = model.fk(program.q[:5])
    assert measurable(T, CellConfig()).all()
    # one orientation for all five poses, positions the standard's
    assert np.abs(pose_error(T, T[:1].repeat(5, 0))[:, 3:]).max() < 1e-6
    for name, q in info["q"].items():
        assert np.allclose(model.fk(np.asarray(q)[None])[0, :3, 3], info["poses"][name], atol=1e-6)
    assert np.all(np.diff(program.t_measure_s) > 0)


def test_cube_of_a_random_arm_and_of_the_ur10():
    for desc in (load_description("ur10"), random_robot(np.random.default_rng(2), 6, False)):
        model = RobotModel(desc)
        cube = find_cube(model, CellConfig(), np.deg2rad(2.0))
        assert cube.edge_m > 0.05
        T = _check_cube(model, cube)
        assert np.abs(pose_error(T, T[:1].repeat(5, 0))[:, 3:]).max() < 1e-6


def test_cube_program_needs_whole_cycles():
    model = RobotModel(load_description("fanuc_m900ib700"))
    config = ProgramConfig(kind="iso9283")
    with pytest.raises(ConfigError, match="5 poses x cycles"):
        make_cube_program(model, 12, config, CellConfig())
    with pytest.raises(ConfigError, match="random programs"):
        make_program(model, 10, np.random.default_rng(0), config)
    with pytest.raises(ConfigError, match="program.kind"):
        ProgramConfig(kind="spiral")
    assert "iso9283" in list_scenarios()
