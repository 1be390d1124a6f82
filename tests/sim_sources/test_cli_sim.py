"""``robocal sim dataset``: writes the campaign, reports its accuracy, fails in one line."""

import json

import pytest

from kinematics.dataset import read_dataset
from stream.cli import main


def test_sim_dataset_writes_and_reports(tmp_path, capsys):
    out = tmp_path / "d.parquet"
    code = main(["sim", "dataset", "--scenario", "nominal", "--n", "20", "--seed", "3",
                 "--out", str(out), "--json"])  # fmt: skip
    assert code == 0
    result = json.loads(capsys.readouterr().out)
    assert result["n"] == 20 and result["scenario"] == "nominal" and result["max_mm"] < 1e-6
    assert len(read_dataset(out)) == 20


def test_sim_dataset_lists_scenarios(capsys):
    assert main(["sim", "dataset", "--list", "--json"]) == 0
    assert "paper" in json.loads(capsys.readouterr().out)["scenarios"]


@pytest.mark.parametrize(
    "argv, message",
    [
        (["--scenario", "nope", "--out", "x.parquet"], "unknown scenario 'nope'"),
        (["--n", "0", "--out", "x.parquet"], "n >= 1"),
        (["--scenario", "paper"], "needs --out"),
        (["--n", "5", "--out", "x.txt"], "end in .parquet or .csv"),
    ],
)
def test_bad_input_is_one_line_and_exit_2(tmp_path, monkeypatch, capsys, argv, message):
    monkeypatch.chdir(tmp_path)
    assert main(["sim", "dataset", *argv]) == 2
    err = capsys.readouterr().err.strip().splitlines()[-1]
    assert err.startswith("robocal: error:") and message in err


def test_scale_zero_without_noise_is_the_nominal_robot(tmp_path, capsys):
    out = tmp_path / "zero.csv"
    argv = [
        "sim",
        "dataset",
        "--n",
        "10",
        "--scale",
        "0",
        "--no-noise",
        "--out",
        str(out),
        "--json",
    ]
    assert main(argv) == 0
    result = json.loads(capsys.readouterr().out)
    assert result["scenario"] == "paper" and result["max_mm"] < 1e-6
