"""Reference poses for a new set-up: greedy D-optimal order over a program's poses."""

import numpy as np
import pytest

from kinematics.calibration import CalibrationConfig, identify, rest_observations
from kinematics.description import load_description
from kinematics.errors import ConfigError
from kinematics.model import RobotModel
from kinematics.reference import RIDGE, position_rows, program_first, reference_order

UR10 = load_description("ur10")


def condition_number(q: np.ndarray) -> float:
    """How well poses ``q`` identify the UR10's geometry and frames (calibration's measure)."""
    model = RobotModel(UR10)
    return identify(model, rest_observations(model, q), CalibrationConfig()).condition_number


@pytest.fixture(scope="module")
def program():
    """A program that dwells in one region for its first 300 poses, then visits the rest."""
    rng = np.random.default_rng(5)
    region = rng.uniform(
        [0.2, -1.6, 0.5, -2.0, 1.0, -0.5], [0.8, -1.0, 1.2, -1.4, 1.6, 0.5], (300, 6)
    )
    rest = rng.uniform(-np.pi, np.pi, (300, 6))
    return np.concatenate([region, rest])


def test_a_programs_reference_poses_identify_what_its_first_poses_cannot(program):
    order = reference_order(UR10, program, 60)
    assert order[0] == 0 and len(set(order.tolist())) == 60
    assert condition_number(program[order]) < condition_number(program[:60]) / 10


def test_each_pose_adds_most_to_the_information_of_those_before_it(program):
    order = reference_order(UR10, program, 12, first=7)
    rows = position_rows(UR10, program)
    information = RIDGE * np.eye(rows.shape[2])
    for i, row in enumerate(order):
        if i:
            gains = [np.linalg.slogdet(information + r.T @ r)[1] for r in rows]
            gains = np.where(np.isin(np.arange(len(rows)), order[:i]), -np.inf, gains)
            assert gains[row] == pytest.approx(np.max(gains), abs=1e-9)
        information += rows[row].T @ rows[row]
    assert order[0] == 7


def test_every_prefix_is_the_order_for_fewer_poses(program):
    full = reference_order(UR10, program, 30)
    for k in (1, 10, 20):
        assert reference_order(UR10, program, k).tolist() == full[:k].tolist()


def test_a_day_meets_its_reference_program_first_then_the_rest_as_recorded(program):
    rows = np.arange(5, len(program), 2)  # the day's rows, ascending
    day = program_first(UR10, program, rows, 12, 30)
    assert day[:12].tolist() == rows[:30][reference_order(UR10, program[rows[:30]], 12)].tolist()
    assert sorted(day.tolist()) == rows.tolist()
    assert np.all(np.diff(day[12:]) > 0)
    assert len(program_first(UR10, program, rows[:8], 12, 30)) == 8  # a window shorter than k


@pytest.mark.parametrize(
    ("q", "k", "first", "says"),
    [
        (np.zeros((5, 6)), 6, 0, "k must be in [1, 5]"),
        (np.zeros((5, 6)), 0, 0, "k must be in [1, 5]"),
        (np.zeros((5, 7)), 1, 0, "need joint angles (N, 6) for ur10, got shape (5, 7)"),
        (np.zeros((5, 6)), 2, 5, "first must be a row in [0, 5)"),
    ],
)
def test_bad_requests_say_what_was_wrong(q, k, first, says):
    with pytest.raises(ConfigError, match=r"reference poses: .*") as info:
        reference_order(UR10, q, k, first)
    assert says in str(info.value) and "\n" not in str(info.value)
