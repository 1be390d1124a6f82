"""A continual learner identifies its physics base again: from every trained point each time
they double, a base left on the nominal from points spread over its replay memory, and a
model file's base that leaves effects out fitted to the stream's points."""

from dataclasses import replace

import numpy as np
import pytest

from kinematics.dataset import Dataset, read_dataset, write_dataset
from kinematics.gap.candidates import make_effect
from kinematics.gap.files import gap_from_files
from kinematics.gap.model_file import EffectEntry, load_model_file, model_to_toml
from kinematics.model import RobotModel
from learner.base import AUTO_MAX_CONDITION, data_frame, identify_base, make_base, nominal_base
from learner.config import ContinualConfig, ModelConfig, TrainConfig
from learner.continual import ContinualLearner
from learner.continual_base import doubled, due, memory_base, refined_base, scheduled, status
from learner.model import ErrorModel
from learner.snapshot import snapshot_from_bytes, snapshot_to_bytes
from learner.workflow import prepare
from sim_sources.unseen import UnseenSpec, write_unseen
from tests.learner.conftest import make_dataset


@pytest.fixture(scope="module")
def corner_first():
    """40 points with q1 in a narrow band, then 360 over the whole range (a real stream)."""
    corner = prepare(make_dataset(40, seed=1, q1_range=(-0.2, 0.2)), test_fraction=0.0)
    rest = prepare(make_dataset(560, seed=2), test_fraction=0.0)
    X = np.concatenate([corner.X, rest.X[:360]])
    Y = np.concatenate([corner.Y, rest.Y[:360]])
    return corner.spec, X, Y, rest.X[360:], rest.Y[360:]


def _base_mm(base, spec, X, Y) -> float:
    E = Y - base.error(spec, X, RobotModel(spec.description))
    return float(np.linalg.norm(E[:, :3], axis=1).mean() * 1e3)


def test_the_schedule_and_which_bases_are_identified_again(corner_first):
    spec, X, Y, _, _ = corner_first
    geometric = identify_base("geometric", spec, X[:40], Y[:40])
    assert status(geometric) == "identified"
    assert status(identify_base("auto", spec, X[:5], Y[:5])) == "nominal"
    assert status(nominal_base(spec.description)) == "fixed"
    assert geometric.condition == pytest.approx(68.6, abs=0.05)  # the corner: weakly identified
    assert not any(due(v, geometric) for v in range(70))  # refined as its points double
    assert [v for v in range(35) if scheduled(v, "nominal")] == [10, 20, 30]
    assert not any(due(v, nominal_base(spec.description)) for v in range(70))
    assert memory_base(geometric, spec, X[:199], Y[:199]) is None  # too few points
    assert [n for n in range(0, 700) if doubled(n, n + 1, 40)] == [39, 79, 159, 319, 639]
    assert refined_base(geometric, spec, X[:8], Y[:8]) is None  # too few to identify it


def test_a_base_from_the_first_points_is_replaced_by_the_memorys(corner_first):
    spec, X, Y, X_test, Y_test = corner_first
    first = identify_base("geometric", spec, X[:40], Y[:40])
    late = memory_base(first, spec, X, Y)
    assert late is not None and late.kind == "geometric" and "200 points" in late.note
    first_mm = _base_mm(first, spec, X_test, Y_test)
    assert _base_mm(late, spec, X_test, Y_test) < 0.8 * first_mm  # 1.04 against 1.41 mm
    refined = refined_base(first, spec, X, Y)
    assert refined.kind == "geometric" and "400 points" in refined.note
    assert _base_mm(refined, spec, X_test, Y_test) < 0.8 * first_mm


@pytest.mark.parametrize("memory", [300, 150])
def test_a_stream_refines_its_base_while_the_memory_holds_every_point(corner_first, memory):
    """40 points, then 36 trained per batch: refined on 112 and 184 points (past 80 and 160);
    with memory 150 on 112 only: at 184 the memory drops points, and the base stays."""
    spec, X, Y, X_test, Y_test = corner_first
    model = ErrorModel.create(
        spec, ModelConfig(hidden_layers=1, neurons=16), TrainConfig(max_epochs=30), seed=0
    )
    cfg = ContinualConfig(
        memory=memory, batch=40, init=40, epochs_per_update=5, init_epochs=30, base="geometric"
    )
    learner = ContinualLearner(model, cfg)
    notes = {m.version: learner.base.note for m in learner.learn_stream(X, Y)}
    assert notes[1].startswith("identified from 40 points")
    last = 184 if memory == 300 else 112
    assert learner.base.kind == "geometric" and f"from {last} points" in learner.base.note
    assert learner.model.base.note == learner.base.note  # published on it
    first = identify_base("geometric", spec, X[:40], Y[:40])
    if memory == 300:
        assert _base_mm(learner.base, spec, X_test, Y_test) < 0.8 * _base_mm(
            first, spec, X_test, Y_test
        )


@pytest.fixture(scope="module")
def drift_day(tmp_path_factory):
    """A random arm with tracker drift: ``robocal gap``'s model file of its first 300 points
    (it names the drift, which a base leaves out), and the 600 points after them."""
    tmp = tmp_path_factory.mktemp("drift")
    arm = UnseenSpec(
        seed=323, n_points=900, hidden="tracker_drift", magnitude=8.0, also=(("geometric", 20.0),)
    )
    ds = read_dataset(write_unseen(arm, tmp)[0])
    first = Dataset(ds.table.iloc[:300].reset_index(drop=True), ds.meta)
    gap = gap_from_files(write_dataset(first, tmp / "first.parquet"))
    assert "tracker_drift" in [e.effect for e in gap.named]
    (tmp / "gap.toml").write_text(model_to_toml(gap.model_file()))
    later = Dataset(ds.table.iloc[300:].reset_index(drop=True), ds.meta)
    return str(tmp / "gap.toml"), later


def test_a_stream_on_a_gap_file_fits_what_it_keeps_again_as_its_points_double(drift_day):
    """The file's geometry was fitted beside the drift; a stream on it as its base fits the
    rest again without it on its first points and each time they double (the base ends
    0.118 mm off on the test points, as filed 0.428, the geometric calibration of every training
    point 0.116), and the snapshot keeps it a base that is fitted again."""
    path, later = drift_day
    p = prepare(later, test_fraction=0.2, seed=0)
    train = np.sort(p.train)
    filed = make_base(path, p.spec, p.X[:0], p.Y[:0], data_frame(later))
    assert status(filed) == "refitted" and filed.left_out == ("tracker_drift",)
    model = ErrorModel.create(
        p.spec, ModelConfig(hidden_layers=1, neurons=16), TrainConfig(max_epochs=20), 0, "", filed
    )
    cfg = ContinualConfig(batch=50, init=50, epochs_per_update=3, init_epochs=20)
    learner = ContinualLearner(model, cfg)
    notes = {m.version: learner.base.note for m in learner.learn_stream(p.X[train], p.Y[train])}
    assert "fitted again on 50 points" in notes[1]
    n = int(learner.base.note.rpartition("fitted again on ")[2].split()[0])
    assert n >= 200 and learner.model.base.note == learner.base.note
    assert learner.base.note.count("fitted again") == 1  # the latest fit replaces the others
    geometric = identify_base("geometric", p.spec, p.X[train], p.Y[train])
    X_test, Y_test = p.X[p.test], p.Y[p.test]
    fitted_mm = _base_mm(learner.base, p.spec, X_test, Y_test)
    assert fitted_mm < 1.15 * _base_mm(geometric, p.spec, X_test, Y_test)
    assert _base_mm(filed, p.spec, X_test, Y_test) > 1.5 * fitted_mm
    again = snapshot_from_bytes(snapshot_to_bytes(learner.model)).base
    assert again.left_out == ("tracker_drift",) and status(again) == "refitted"


def test_a_file_base_is_fitted_again_only_where_the_points_identify_all_it_fits(
    drift_day, tmp_path
):
    """With a gear correction in the file (36 parameters), 100 points from a 1 rad band of
    joint 2 identify the fit poorly (condition number 6.9e3): the base stays as it is; 300
    points over the whole range identify it (89) and it is fitted again, each parameter the
    file gives a std, one estimated at exactly zero too."""
    path, later = drift_day
    p = prepare(later, test_fraction=0.2, seed=0)
    model = load_model_file(path)
    names = make_effect("gear_periodic", {"orders": [1, 2, 3]}).parameter_names(model.description)
    gear = EffectEntry(
        name="gear_periodic",
        options={"orders": [1, 2, 3]},
        parameters=dict.fromkeys(names, 1e-4) | {names[0]: 0.0},  # estimated at 0: a std
        std=dict.fromkeys(names, 1e-5),
        identified=False,
    )
    (tmp_path / "gear.toml").write_text(
        model_to_toml(replace(model, effects=(*model.effects, gear)))
    )
    filed = make_base(str(tmp_path / "gear.toml"), p.spec, p.X[:0], p.Y[:0], data_frame(later))
    band = np.flatnonzero(np.abs(p.X[:, 1] - np.median(p.X[:, 1])) < 0.5)[:100]
    assert len(band) == 100 and refined_base(filed, p.spec, p.X[band], p.Y[band]) is None
    spread = refined_base(filed, p.spec, p.X[:300], p.Y[:300])
    assert spread is not None and spread.condition < AUTO_MAX_CONDITION
    assert [e.name for e in spread.effects] == ["gear_periodic"]
    assert spread.effects[0].parameters[names[0]] != 0.0  # fitted: the file estimated it
