import json

import pytest
import torch

from kinematics.dataset import write_dataset
from learner.snapshot import load_snapshot
from stream.cli import main
from tests.learner.conftest import make_dataset


@pytest.fixture(scope="module")
def data_file(tmp_path_factory):
    torch.set_num_threads(1)
    path = tmp_path_factory.mktemp("learn") / "synthetic.parquet"
    write_dataset(make_dataset(160, seed=2), path)
    return path


def _json(capsys):
    return json.loads(capsys.readouterr().out)


def test_train_then_evaluate(data_file, tmp_path, capsys):
    model = tmp_path / "m.safetensors"
    argv = ["train", "--data", str(data_file), "--out", str(model), "--max-epochs", "3", "--json"]
    assert main(argv) == 0
    out = _json(capsys)
    assert out["n_train"] == 144 and out["epochs"] == 3
    assert {"mean_mm", "coverage_90", "improvement_pct"} <= set(out["test"])
    assert load_snapshot(model).robot == "fanuc_m900ib700"
    assert main(["evaluate", "--model", str(model), "--data", str(data_file), "--json"]) == 0
    report = _json(capsys)
    assert report["n"] == 160 and report["mean_mm"] > 0
    assert main(["evaluate", "--model", str(model), "--data", str(data_file)]) == 0
    assert "90% interval covers" in capsys.readouterr().out


def test_continual_writes_model_and_curve(data_file, tmp_path, capsys):
    model = tmp_path / "c.safetensors"
    argv = [
        "continual",
        "--data",
        str(data_file),
        "--memory",
        "40",
        "--batch",
        "40",
        "--init",
        "30",
        "--epochs-per-update",
        "2",
        "--out",
        str(model),
        "--json",
    ]
    assert main(argv) == 0
    out = _json(capsys)
    assert out["updates"] == 4  # init + ceil((144 - 30) / 40)
    csv = (tmp_path / "c.curve.csv").read_text().splitlines()
    assert len(csv) == 5 and "mean_mm" in csv[0]
    assert (tmp_path / "c.curve.png").stat().st_size > 1000
    assert model.exists()


def test_experiment_quick(data_file, tmp_path, capsys, monkeypatch):
    from learner import experiment

    quick = experiment.StudyConfig(
        sizes=(40,),
        repeats=1,
        batches=(60,),
        memories=(40,),
        max_epochs=2,
        epochs_per_update=1,
        sgpr=False,
    )
    monkeypatch.setattr(experiment.StudyConfig, "quick", classmethod(lambda cls, seed=0: quick))
    argv = ["experiment", "paper", "--data", str(data_file), "--out", str(tmp_path), "--quick"]
    assert main(argv) == 0
    text = capsys.readouterr().out
    assert "joints only" in text and "n_B=60, N_m=40" in text
    rows = json.loads((tmp_path / "study.json").read_text())["rows"]
    assert len(rows) == 5 + 1 + 1  # five feature/encoding rows, one size, one continual
    assert (tmp_path / "size.png").exists()


def test_bad_input_exits_2(tmp_path, capsys):
    assert main(["evaluate", "--model", str(tmp_path / "no.safetensors"), "--data", "x.csv"]) == 2
    assert "robocal: error:" in capsys.readouterr().err
