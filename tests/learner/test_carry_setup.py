"""A model carried onto a tracker set up anew (``ContinualConfig.new_setup``): the day's own
estimate of its tracker frame, a nominal fit to its first points, does not hold the carry; and a
day that starts with a reference program (``reference_program``) fits the arm's geometry too."""

from dataclasses import replace

import numpy as np
import pytest

from kinematics.errors import ConfigError
from kinematics.frames import fit_frames
from kinematics.model import RobotModel
from kinematics.reference import reference_order
from kinematics.transforms import apply_error, invert, pose_error, transform_from_xyz_rpy
from learner.base import identify_base
from learner.config import ContinualConfig, ModelConfig, TrainConfig
from learner.continual import ContinualLearner
from learner.metrics import interval_coverage
from learner.model import ErrorModel
from learner.snapshot import snapshot_from_bytes, snapshot_to_bytes
from learner.workflow import prepare
from tests.learner.conftest import make_dataset


@pytest.fixture(scope="module")
def day():
    """A model of 200 points of the perturbed Fanuc on its geometric base; the tracker set up
    anew, metres away; the day's first 30 points, all near one pose, and its frame as the
    nominal model fits them (what an importer of those points gives)."""
    p = prepare(make_dataset(300, seed=3), test_fraction=0.0)
    base = identify_base("geometric", p.spec, p.X[:200], p.Y[:200])
    model = ErrorModel.create(
        p.spec, ModelConfig(hidden_layers=2, neurons=32), TrainConfig(max_epochs=60), 0, base=base
    )
    model.fit(p.X[:200], p.Y[:200])
    T_nominal = RobotModel(p.spec.description).fk(p.X[:, :6])
    setup = transform_from_xyz_rpy([0.8, -1.5, 0.2], [0.01, -0.02, 2.0])
    tracker = setup[None] @ apply_error(T_nominal, p.Y)
    first = np.argsort(np.linalg.norm(p.X[:, :6] - p.X[7, :6], axis=1))[:30]
    estimate = fit_frames(tracker[first], T_nominal[first], T_6_S_init=np.eye(4)).T_W_0
    return p, model, T_nominal, tracker, first, {"true": setup, "estimated": estimate}


def carried_tracker_positions(day, frame: str, new_setup: bool) -> tuple[np.ndarray, str]:
    """The tracker-frame positions (m) the base predicts after a carry on the first points,
    the labels in the day's ``frame`` (the true set-up or its estimate), and the base's note."""
    p, model, T_nominal, tracker, first, frames = day
    W = frames[frame]
    Y = pose_error(invert(W)[None] @ tracker, T_nominal)
    learner = ContinualLearner(
        snapshot_from_bytes(snapshot_to_bytes(model)), ContinualConfig(new_setup=new_setup)
    )
    learner.carry(p.X[first], Y[first])
    poses = W[None] @ learner.base.poses(p.spec, p.X)
    return poses[:, :3, 3], learner.base.note


def test_a_new_setup_fits_its_tracker_frame_whatever_the_days_estimate_of_it(day):
    """The estimate is millimetres off the set-up; a new set-up's carry lands on the same
    tracker-frame predictions from either, a held one does not."""
    _, _, _, _, _, frames = day
    assert np.linalg.norm(frames["estimated"][:3, 3] - frames["true"][:3, 3]) > 1e-3
    true, note = carried_tracker_positions(day, "true", new_setup=True)
    estimated, _ = carried_tracker_positions(day, "estimated", new_setup=True)
    assert note.split("; ")[-2] == "tracker set up anew, its frame free"
    assert np.abs(true - estimated).max() < 2e-6
    held_true, _ = carried_tracker_positions(day, "true", new_setup=False)
    held_estimated, _ = carried_tracker_positions(day, "estimated", new_setup=False)
    assert np.abs(held_true - held_estimated).max() > 2e-5


@pytest.mark.parametrize("n_first", [30, 10])
def test_a_lost_beam_among_the_first_points_does_not_set_the_days_frame(day, n_first):
    """One of the 30 first points 1 m off (a lost beam at set-up) had moved the freely fitted
    base by 33 mm over the day; the carry leaves it out, also where it is one of only 10."""
    p, model, T_nominal, tracker, first, frames = day
    first = first[:n_first]
    Y = pose_error(invert(frames["true"])[None] @ tracker, T_nominal)
    lost = Y.copy()
    lost[first[5], 0] += 1.0
    carried = []
    for labels in (Y, lost):
        learner = ContinualLearner(
            snapshot_from_bytes(snapshot_to_bytes(model)), ContinualConfig(new_setup=True)
        )
        learner.carry(p.X[first], labels[first])
        carried.append(learner.base.poses(p.spec, p.X)[:, :3, 3])
    assert np.abs(carried[1] - carried[0]).max() < 2e-5


def test_new_setup_must_be_a_boolean():
    with pytest.raises(ConfigError, match="continual.new_setup must be true or false, got 'yes'"):
        ContinualConfig(new_setup="yes")


@pytest.fixture(scope="module")
def longer_arm(day):
    """The same day's tracker poses with the arm's second link 1.5 mm longer than the model's
    base says (the arm changed since, not only its tracker)."""
    p, model, T_nominal, tracker, _, frames = day
    desc = model.base.description
    joints = list(desc.joints)
    joints[1] = replace(joints[1], a_m=joints[1].a_m + 1.5e-3)
    longer = RobotModel(replace(desc, joints=tuple(joints))).fk(p.X[:, :6])
    moved = tracker.copy()
    shift = longer[:, :3, 3] - RobotModel(desc).fk(p.X[:, :6])[:, :3, 3]
    moved[:, :3, 3] += shift @ frames["true"][:3, :3].T
    return moved


def carry_onto(day, tracker, rows, reference_program):
    """A new-set-up carry on ``rows`` of the day (labels in its true frame): the base's
    tracker-frame positions (m) at every point, and its note."""
    p, model, T_nominal, _, _, frames = day
    W = frames["true"]
    Y = pose_error(invert(W)[None] @ tracker, T_nominal)
    cfg = ContinualConfig(new_setup=True, reference_program=reference_program)
    learner = ContinualLearner(snapshot_from_bytes(snapshot_to_bytes(model)), cfg)
    learner.carry(p.X[rows], Y[rows])
    return (W[None] @ learner.base.poses(p.spec, p.X))[:, :3, 3], learner.base.note


def test_a_reference_program_fits_the_days_geometry_where_its_points_identify_it(day, longer_arm):
    """Carried on 60 reference poses, the base follows the longer link to within a third of
    what the frames alone leave of it, on the day's other points."""
    p, tracker = day[0], day[3]
    program = reference_order(p.spec.description, p.X[:, :6], 60)
    rest = np.setdiff1d(np.arange(len(p.X)), program)
    change = (longer_arm - tracker)[rest, :3, 3]
    left = {}
    for reference in (True, False):
        longer, note = carry_onto(day, longer_arm, program, reference_program=reference)
        before, _ = carry_onto(day, tracker, program, reference_program=reference)
        left[reference] = np.linalg.norm(longer[rest] - before[rest] - change, axis=1).mean()
        if reference:
            assert "reference program: geometry and joint compliance fitted again on its 60" in note
    assert np.linalg.norm(change, axis=1).mean() > 1e-3
    assert left[True] < left[False] / 3


def test_a_reference_program_too_short_for_the_geometry_keeps_it_and_says_so(day, longer_arm):
    first = day[4][:8]
    kept, note = carry_onto(day, longer_arm, first, reference_program=True)
    framed, _ = carry_onto(day, longer_arm, first, reference_program=False)
    assert "reference program: geometry kept, calibration needs at least" in note
    np.testing.assert_array_equal(kept, framed)


def test_reference_program_must_be_a_boolean():
    with pytest.raises(ConfigError, match="continual.reference_program must be true or false"):
        ContinualConfig(reference_program=1)


def test_a_reference_program_checks_the_intervals_itself(day, longer_arm):
    """Its poses are spread over the workspace, so the base fitted again without each fold
    checks the intervals everywhere: the day starts trusted, its 90 % intervals no narrower
    than those folds need; frames alone on the same poses start it unverified."""
    p, model, T_nominal, _, _, frames = day
    Y = pose_error(invert(frames["true"])[None] @ longer_arm, T_nominal)
    program = reference_order(p.spec.description, p.X[:, :6], 60)
    rest = np.setdiff1d(np.arange(len(p.X)), program)
    covered, marks = {}, {}
    for reference in (True, False):
        cfg = ContinualConfig(new_setup=True, reference_program=reference)
        learner = ContinualLearner(snapshot_from_bytes(snapshot_to_bytes(model)), cfg)
        learner.carry(p.X[program], Y[program])
        covered[reference] = interval_coverage(learner.model.predict(p.X[rest]), Y[rest], 0.9)
        marks[reference] = learner.model.unverified
    assert marks[True] == "" and marks[False]
    assert 0.8 <= covered[True] <= 0.98 < covered[False]  # measured 0.972 against 1.0
