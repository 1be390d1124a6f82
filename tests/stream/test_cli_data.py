"""``robocal import ipa``, ``robocal data summary`` and ``robocal data reference-poses``, run
in-process through ``main``."""

import json
import re

import numpy as np
import pandas as pd
import pytest

from kinematics.dataset import Dataset, DatasetMeta, meta_path, write_dataset
from kinematics.description import load_description
from kinematics.importers.ipa import import_series
from kinematics.model import RobotModel
from kinematics.transforms import xyz_quat_from_transform
from stream.cli import main

Q = [f"q{i}" for i in range(1, 7)]
KEYS = {"n", "mean_mm", "std_mm", "max_mm", "p95_mm", "mean_arcmin", "max_arcmin"}


@pytest.fixture
def dataset_csv(tmp_path):
    """A 30-point UR10 dataset in the base frame, every point 2 mm off along z."""
    q = np.random.default_rng(0).uniform(-2.0, 2.0, (30, 6))
    T = RobotModel(load_description("ur10")).fk(q)
    T[:, 2, 3] += 2e-3
    xyz, quat = xyz_quat_from_transform(T)
    table = pd.DataFrame({"t": np.arange(30.0)})
    for i in range(6):
        table[f"q{i + 1}"] = q[:, i]
    for i, c in enumerate(("x", "y", "z", "qx", "qy", "qz", "qw")):
        table[c] = np.concatenate([xyz, quat], axis=1)[:, i]
    return write_dataset(Dataset(table, DatasetMeta(robot="ur10")), tmp_path / "d.csv")


def test_summary_json(dataset_csv, tmp_path, capsys):
    hist = tmp_path / "h.png"
    assert main(["data", "summary", str(dataset_csv), "--json", "--hist", str(hist)]) == 0
    result = json.loads(capsys.readouterr().out)
    assert set(result) == KEYS and result["n"] == 30
    assert result["mean_mm"] == pytest.approx(2.0, abs=1e-9)
    assert result["max_arcmin"] == pytest.approx(0.0, abs=1e-3)
    assert hist.read_bytes()[:4] == b"\x89PNG"


def test_summary_text(dataset_csv, capsys):
    assert main(["data", "summary", str(dataset_csv), "--robot", "ur10"]) == 0
    assert "mean 2.000 mm" in capsys.readouterr().out


def joint_too_far(table: pd.DataFrame) -> pd.DataFrame:
    table.loc[4, "q2"] = 7.0
    return table


@pytest.mark.parametrize(
    "edit, args, message",
    [
        (None, ["--robot", "nope"], "unknown robot 'nope'"),
        (lambda t: t.drop(columns=["qw"]), [], r"missing column\(s\) qw"),
        (lambda t: t.assign(z=np.nan), [], "row 0, column 'z': value is not a finite"),
        (joint_too_far, [], "row 4, column 'q2': 401.070 deg"),
    ],
)
def test_summary_bad_input_exits_2(dataset_csv, capsys, edit, args, message):
    if edit is not None:
        edit(pd.read_csv(dataset_csv)).to_csv(dataset_csv, index=False)
    assert main(["data", "summary", str(dataset_csv), *args]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and err.startswith("robocal: error: ")
    assert re.search(message, err)


def test_summary_missing_file_and_meta(dataset_csv, tmp_path, capsys):
    assert main(["data", "summary", str(tmp_path / "none.parquet")]) == 2
    assert "no such dataset file" in capsys.readouterr().err
    meta_path(dataset_csv).unlink()
    assert main(["data", "summary", str(dataset_csv)]) == 2
    assert "no metadata" in capsys.readouterr().err


def test_import_missing_folder_exits_2(tmp_path, capsys):
    assert main(["import", "ipa", str(tmp_path / "nope"), "--out", str(tmp_path / "o.csv")]) == 2
    assert "no such series folder" in capsys.readouterr().err


@pytest.mark.shared_data
def test_import_then_summarise_series_b(shared_data, tmp_path, capsys):
    out = tmp_path / "b.parquet"
    folder = shared_data / "ur10-ipa" / "Series_B"
    assert main(["import", "ipa", str(folder), "--out", str(out), "--json"]) == 0
    imported = json.loads(capsys.readouterr().out)
    assert imported["n"] == 1495 and imported["time_source"] == "row_order"
    assert np.asarray(imported["T_W_0"]).shape == (4, 4)
    assert main(["data", "summary", str(out), "--json"]) == 0
    summary = json.loads(capsys.readouterr().out)
    # With frames identified from the data, the summary equals the fit residual.
    assert summary["mean_mm"] == pytest.approx(imported["fit_mean_mm"], rel=1e-9)
    assert 0.5 < summary["mean_mm"] < 1.5


@pytest.mark.shared_data
def test_import_a_new_days_frames_from_its_first_rows(shared_data, tmp_path, capsys):
    """A new day imported as its start knows it: frames from its first 100 rows, which fit
    those rows better and the whole series worse than frames from every row do."""
    folder = shared_data / "ur10-ipa" / "Series_B"
    out = tmp_path / "b100.parquet"
    args = ["import", "ipa", str(folder), "--out", str(out), "--frames-rows", "100", "--json"]
    assert main(args) == 0
    imported = json.loads(capsys.readouterr().out)
    assert imported["frames_rows"] == 100 and imported["n"] == 1495
    every = import_series(folder).dataset
    assert not np.allclose(imported["T_W_0"], every.meta.T_W_0, atol=1e-5)
    assert main(["data", "summary", str(out), "--json"]) == 0
    assert json.loads(capsys.readouterr().out)["mean_mm"] > every.meta.extra["frame_fit"]["mean_mm"]
    assert main([*args[:-3], "--frames-rows", "2"]) == 2
    assert "frames_rows must be in [3, 1495] rows, got 2" in capsys.readouterr().err


def test_reference_poses_writes_the_programs_rows_in_order(dataset_csv, tmp_path, capsys):
    out = tmp_path / "first.csv"
    args = ["data", "reference-poses", str(dataset_csv), "--robot", "ur10", "--n", "10"]
    args += ["--out", str(out)]
    assert main([*args, "--first", "3", "--json"]) == 0
    result = json.loads(capsys.readouterr().out)
    poses, program = pd.read_csv(out), pd.read_csv(dataset_csv)
    assert result["rows"] == poses["row"].tolist() and poses["row"].iloc[0] == 3
    assert len(set(result["rows"])) == 10 and list(poses.columns) == ["row", *Q]
    np.testing.assert_array_equal(poses[Q].to_numpy(), program[Q].to_numpy()[poses["row"]])


@pytest.mark.parametrize(
    ("table", "n", "says"),
    [
        (pd.DataFrame({"a": [1.0, 2.0]}), "1", "no joint angle columns q1..qn"),
        (pd.DataFrame({"q1": [1.0, np.nan]}), "1", "must be finite numbers"),
        (pd.DataFrame({f"q{i}": [1.0, 2.0] for i in range(1, 7)}), "3", "k must be in [1, 2]"),
        (pd.DataFrame({"q1": [1.0, 2.0]}), "1", "need joint angles (N, 6) for ur10"),
    ],
)
def test_reference_poses_refuse_a_bad_program_in_one_line(tmp_path, capsys, table, n, says):
    table.to_csv(tmp_path / "p.csv", index=False)
    args = ["data", "reference-poses", str(tmp_path / "p.csv"), "--robot", "ur10", "--n", n]
    assert main([*args, "--out", str(tmp_path / "o.csv")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and says in err[0] and not (tmp_path / "o.csv").exists()
