"""One rule for robot identity: a dataset matches a description by joint count and name."""

import json
from dataclasses import replace

import pytest

from kinematics.dataset import Dataset, DatasetMeta, read_dataset, write_dataset
from kinematics.description import description_to_toml, load_description
from kinematics.errors import DatasetError
from kinematics.identity import check_match, description_for, reference_name
from sim_sources.unseen import UnseenSpec, write_unseen
from stream.cli import main


@pytest.fixture(scope="module")
def unseen(tmp_path_factory):
    """A 6-axis arm not among the shipped robots, its dataset naming it by an absolute path."""
    out = tmp_path_factory.mktemp("unseen")
    spec = UnseenSpec(seed=11, n_points=240, n_axes=6, hidden="backlash", n_thermometers=3)
    path, desc, _ = write_unseen(spec, out)
    return path, desc


def test_gap_and_data_summary_accept_a_robot_given_by_path(unseen, capsys):
    path, desc = unseen
    assert read_dataset(path).meta.robot.endswith("robot.toml")
    assert main(["gap", "--data", str(path), "--json"]) == 0
    out = json.loads(capsys.readouterr().out)
    assert out["robot"] == desc.name
    assert [e["effect"] for e in out["named_effects"]] == ["backlash"]
    assert main(["data", "summary", str(path), "--json"]) == 0
    assert json.loads(capsys.readouterr().out)["n"] == 240


def test_relative_path_resolves_next_to_the_dataset(unseen, tmp_path, monkeypatch):
    path, desc = unseen
    ds = read_dataset(path)
    folder = tmp_path / "moved"
    (folder / "robots").mkdir(parents=True)
    (folder / "robots" / "arm.toml").write_text(description_to_toml(desc))
    moved = write_dataset(
        Dataset(ds.table, replace(ds.meta, robot="robots/arm.toml")), folder / "d.parquet"
    )
    monkeypatch.chdir(tmp_path)  # not the dataset's folder
    assert description_for(read_dataset(moved), None, moved).name == desc.name
    assert reference_name("robots/arm.toml", moved) == desc.name


def test_mismatch_by_name_or_joint_count_is_one_line(unseen):
    path, desc = unseen
    ds = read_dataset(path)
    with pytest.raises(DatasetError, match=r"\(arm_.*\)', description is 'ur10'"):
        check_match(load_description("ur10"), ds, path)
    five = replace(desc, joints=desc.joints[:5])
    with pytest.raises(DatasetError, match="6 joint columns, robot .* has 5"):
        check_match(five, ds, path)
    # a calibrated copy keeps the name and matches
    check_match(desc.with_tool(desc.tool), ds, path)


def test_unreadable_reference_needs_robot_and_then_counts_joints(unseen, tmp_path):
    path, desc = unseen
    ds = read_dataset(path)
    lost = Dataset(ds.table, DatasetMeta(**{**ds.meta.__dict__, "robot": "/gone/arm.toml"}))
    with pytest.raises(DatasetError, match="cannot be loaded .*; pass --robot"):
        description_for(lost)
    robot = tmp_path / "arm.toml"
    robot.write_text(description_to_toml(desc))
    assert description_for(lost, robot).name == desc.name
