"""Reference poses for a new set-up: farthest-point order in joint space."""

import numpy as np
import pytest

from kinematics.errors import ConfigError
from kinematics.reference import reference_order


def test_each_pose_is_the_farthest_from_those_before_it():
    q = np.random.default_rng(3).uniform(-3.0, 3.0, (400, 6))
    order = reference_order(q, 30, first=7)
    assert order[0] == 7 and len(set(order.tolist())) == 30
    for i in range(1, 30):
        gaps = np.linalg.norm(q[:, None] - q[order[:i]][None], axis=2).min(axis=1)
        assert gaps[order[i]] == pytest.approx(gaps.max())


def test_every_prefix_is_the_order_for_fewer_poses():
    q = np.random.default_rng(4).normal(size=(200, 7))
    full = reference_order(q, 50)
    for k in (1, 10, 25):
        assert reference_order(q, k).tolist() == full[:k].tolist()


def test_a_clustered_program_is_left_for_its_far_poses():
    """A program that dwells 190 poses in one region and visits 10 others: the reference
    program measures the 10 far poses before a second one of the region."""
    rng = np.random.default_rng(5)
    region = rng.normal(0.0, 0.05, (190, 6))
    far = rng.uniform(-3.0, 3.0, (10, 6))
    far[:, 0] += np.sign(far[:, 0]) * 1.0  # every far pose at least 1 rad out in joint 1
    q = np.concatenate([region, far])
    order = reference_order(q, 11)
    assert order[0] == 0 and sorted(order[1:].tolist()) == list(range(190, 200))


@pytest.mark.parametrize(
    ("q", "k", "first", "says"),
    [
        (np.zeros((5, 6)), 6, 0, "k must be in [1, 5]"),
        (np.zeros((5, 6)), 0, 0, "k must be in [1, 5]"),
        (np.zeros(6), 1, 0, "shape (6,)"),
        (np.zeros((5, 6)), 2, 5, "first must be a row in [0, 5)"),
    ],
)
def test_bad_requests_say_what_was_wrong(q, k, first, says):
    with pytest.raises(ConfigError, match=r"reference poses: .*") as info:
        reference_order(q, k, first)
    assert says in str(info.value) and "\n" not in str(info.value)
