import csv
import json
from pathlib import Path

import numpy as np
import pytest
import torch
from threadpoolctl import threadpool_info, threadpool_limits

from kinematics.dataset import temperature_columns, write_dataset
from learner.snapshot import load_snapshot, save_snapshot
from sim_sources.unseen import UnseenSpec, write_unseen
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


def _continual(capsys, data: Path, out: Path, *options: str) -> dict:
    """``robocal continual`` on ``data`` in batches of 40, 2 epochs per update, writing ``out``
    (exit 0): its JSON result."""
    argv = ["continual", "--data", str(data), "--batch", "40", "--epochs-per-update", "2"]
    assert main([*argv, *options, "--out", str(out), "--json"]) == 0
    return _json(capsys)


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
    assert report["envelope"]["n_outside"] == 0  # its own data: every pose was trained on
    assert report["envelope"]["inside"]["n"] == 160
    assert report["unverified"] == ""
    assert main(["evaluate", "--model", str(model), "--data", str(data_file)]) == 0
    assert "90% interval covers" in capsys.readouterr().out
    carried = load_snapshot(model)  # as a carry that took the frames as moved leaves it
    carried.unverified = "the frames moved on this day (30 points)"
    save_snapshot(carried, tmp_path / "carried.safetensors")
    assert (
        main(
            ["evaluate", "--model", str(tmp_path / "carried.safetensors"), "--data", str(data_file)]
        )
        == 0
    )
    assert "unverified: the frames moved on this day (30 points)" in capsys.readouterr().out


def test_train_measures_the_drift_a_later_day_needs_or_not_at_fraction_zero(
    data_file, tmp_path, capsys
):
    model = tmp_path / "d.safetensors"
    argv = ["train", "--data", str(data_file), "--out", str(model), "--max-epochs", "3"]
    assert main([*argv, "--drift-fraction", "0.4", "--json"]) == 0  # 58 of 144 points last
    drift = _json(capsys)["drift_scale"]
    assert len(drift) == 6 and min(drift) >= 1.0
    np.testing.assert_allclose(load_snapshot(model).drift_scale, drift, atol=5e-4)
    assert main([*argv, "--drift-fraction", "0"]) == 0
    assert "a later day needs its intervals 1.0 x wider" in capsys.readouterr().out
    np.testing.assert_array_equal(load_snapshot(model).drift_scale, np.ones(6))
    assert main([*argv, "--drift-fraction", "1.5"]) == 2
    assert "train.drift_fraction must be in [0, 1), got 1.5" in capsys.readouterr().err


def evaluate_envelope(model: Path, data: Path) -> int:
    """How many of ``data``'s poses lie past ``model``'s envelope (learner.workflow's count)."""
    from kinematics.dataset import read_dataset
    from learner.metrics import envelope_report
    from learner.workflow import evaluation_points

    m = load_snapshot(model)
    return envelope_report(m, *evaluation_points(m, read_dataset(data)))["n_outside"]


def test_evaluate_names_the_poses_past_the_angles_trained_on(tmp_path, capsys):
    """A model of one half of q1's range on the other half: evaluate says how much of it lies
    there and how the rest fares."""
    ds = make_dataset(240, q1_range=(-2.0, 0.0))
    write_dataset(ds, tmp_path / "left.parquet")
    write_dataset(make_dataset(120, seed=3, q1_range=(-2.0, 2.0)), tmp_path / "all.parquet")
    model = tmp_path / "m.safetensors"
    argv = ["train", "--data", str(tmp_path / "left.parquet"), "--out", str(model)]
    assert main([*argv, "--max-epochs", "3", "--json"]) == 0
    capsys.readouterr()
    argv = ["evaluate", "--model", str(model), "--data", str(tmp_path / "all.parquet")]
    assert main([*argv, "--json"]) == 0
    envelope = _json(capsys)["envelope"]
    assert 0.35 < envelope["outside_share"] < 0.55  # q1 > 0 (+5°): half the poses
    assert envelope["inside"]["n"] == 120 - envelope["n_outside"]
    assert envelope["n_past_joints"] + envelope["n_past_temperatures_only"] == envelope["n_outside"]
    assert main(argv) == 0
    assert "of the poses lie past the joint angles" in capsys.readouterr().out
    warm = make_dataset(120, seed=4, q1_range=(-2.0, 0.0))  # the trained half, 30 K warmer
    warm.table[temperature_columns(warm.table)] += 30.0
    write_dataset(warm, tmp_path / "warm.parquet")
    warm_argv = ["evaluate", "--model", str(model), "--data", str(tmp_path / "warm.parquet")]
    assert main([*warm_argv, "--json"]) == 0
    hot = _json(capsys)["envelope"]
    assert hot["n_outside"] == 120 and hot["n_past_temperatures_only"] > 100
    # carried into that day, continual says the same of the day's poses before it learns them
    day = ["--from", str(model), "--test-fraction", "0", "--init", "40"]
    out = _continual(capsys, tmp_path / "all.parquet", tmp_path / "m2.safetensors", *day)
    assert out["day_past_envelope"] == envelope["outside_share"]
    assert not evaluate_envelope(tmp_path / "m2.safetensors", tmp_path / "all.parquet")


def test_train_on_a_gap_base_in_one_step(data_file, tmp_path, capsys):
    spec = UnseenSpec(seed=4, n_points=300, hidden="joint_compliance", also=(("geometric", 10),))
    data, _, _ = write_unseen(spec, tmp_path / "arm")
    model = tmp_path / "g.safetensors"
    argv = ["train", "--data", str(data), "--out", str(model), "--max-epochs", "3"]
    assert main([*argv, "--base", "gap", "--json"]) == 0
    out = _json(capsys)
    assert out["base"]["kind"] == "gap" and "named joint_compliance" in out["base"]["note"]
    assert load_snapshot(model).base.kind == "gap"
    assert main(["evaluate", "--model", str(model), "--data", str(data), "--json"]) == 0
    assert _json(capsys)["mean_mm"] < out["test"]["mean_mm"] * 1.5  # the same base, all points
    # a dataset whose thermometers are not the ones the description maps: one line, exit 2
    argv = ["train", "--data", str(data_file), "--out", str(model), "--base", "gap"]
    assert main(argv) == 2
    assert "temperature channel(s)" in capsys.readouterr().err
    # a stream cannot identify a gap model from its first points: one line, exit 2
    argv = ["continual", "--data", str(data), "--out", str(model), "--base", "gap"]
    assert main(argv) == 2
    assert "`robocal gap`'s model file" in capsys.readouterr().err.splitlines()[-1]


def test_train_on_few_points_keeps_the_bases_they_identify(tmp_path, capsys):
    """Few points: the default ``best`` trains on what they identify and says why it left the
    rest out (40: the gap workflow's own split is too small; 30: the calibration too);
    ``--base geometric`` stops with one line."""
    for n, kind, why in [(40, "geometric", "no gap base: calibration needs"), (30, "nominal", "")]:
        write_dataset(make_dataset(n, seed=5), tmp_path / "few.parquet")
        out = tmp_path / "m.safetensors"
        argv = ["train", "--data", str(tmp_path / "few.parquet"), "--out", str(out)]
        assert main([*argv, "--max-epochs", "3", "--json"]) == 0
        base = _json(capsys)["base"]
        assert base["kind"] == kind and why in base["note"], base
    assert "nominal: calibration needs at least" in base["note"], base
    assert main([*argv, "--max-epochs", "3", "--base", "geometric"]) == 2
    assert "calibration needs at least" in capsys.readouterr().err.splitlines()[-1]


def test_train_keeps_the_base_that_predicts_its_validation_points_better(
    data_file, tmp_path, capsys
):
    """The default ``--base best``: on an arm whose compliance the gap model names, the gap
    base; where the data cannot form a gap model, the geometric base, and the note says why."""
    spec = UnseenSpec(seed=4, n_points=300, hidden="joint_compliance", also=(("geometric", 10),))
    data, _, _ = write_unseen(spec, tmp_path / "arm")
    argv = ["train", "--data", str(data), "--out", str(tmp_path / "b.safetensors")]
    assert main([*argv, "--max-epochs", "3", "--json"]) == 0
    out = _json(capsys)
    note = out["base"]["note"]
    assert out["base"]["kind"] == "gap" and "chosen on 27 validation points" in note
    geometric, gap = (float(note.split(f"{k} ")[-1].split(" mm")[0]) for k in ("geometric", "gap"))
    assert gap < geometric
    assert load_snapshot(tmp_path / "b.safetensors").base.note == note
    argv = ["train", "--data", str(data_file), "--out", str(tmp_path / "g.safetensors")]
    assert main([*argv, "--max-epochs", "3", "--json"]) == 0
    out = _json(capsys)
    assert out["base"]["kind"] == "geometric" and "no gap base:" in out["base"]["note"]
    # an arm with a geometric error alone: the gap model is the geometric base, trained once
    spec = UnseenSpec(seed=5, n_points=300, also=(("geometric", 10),))
    data, _, _ = write_unseen(spec, tmp_path / "geometric")
    argv = ["train", "--data", str(data), "--out", str(tmp_path / "g.safetensors")]
    assert main([*argv, "--max-epochs", "3", "--json"]) == 0
    out = _json(capsys)
    assert out["base"]["kind"] == "geometric" and "names no effect" in out["base"]["note"]


def test_continual_writes_model_and_curve(data_file, tmp_path, capsys):
    model = tmp_path / "c.safetensors"
    out = _continual(capsys, data_file, model, "--memory", "40", "--init", "30")
    assert out["updates"] == 4  # init + ceil((144 - 30) / 40)
    csv = (tmp_path / "c.curve.csv").read_text().splitlines()
    assert len(csv) == 5 and "mean_mm" in csv[0]
    assert (tmp_path / "c.curve.png").stat().st_size > 1000
    assert model.exists()


def test_continual_update_points_bound_the_epochs(data_file, tmp_path, capsys):
    # 2 epochs over up to 20 memory points: 1 epoch once the 40-point memory is full
    model = tmp_path / "c.safetensors"
    _continual(capsys, data_file, model, "--memory", "40", "--init", "30", "--update-points", "20")
    rows = list(csv.DictReader((tmp_path / "c.curve.csv").open()))
    assert [(r["memory_size"], r["epochs"]) for r in rows[-2:]] == [("40", "1"), ("40", "1")]


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


@pytest.mark.parametrize("flag", ["--new-setup", "--reference-program"])
def test_a_new_days_statement_without_a_model_to_carry_stops_in_one_line(
    data_file, tmp_path, flag, capsys
):
    argv = ["continual", "--data", str(data_file), "--out", str(tmp_path / "m.safetensors")]
    assert main([*argv, flag]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and f"{flag} describes a day carried from a model" in err[0]
    assert not (tmp_path / "m.safetensors").exists()


def test_continual_goes_on_from_a_model_with_its_memory(data_file, tmp_path, capsys):
    first, second = tmp_path / "day1.safetensors", tmp_path / "day2.safetensors"
    argv = ["train", "--data", str(data_file), "--out", str(first), "--max-epochs", "3"]
    assert main(argv) == 0
    assert (tmp_path / "day1.state.safetensors").is_file()  # the memory travels beside it
    capsys.readouterr()
    carry = ["--from", str(first), "--test-fraction", "0", "--init", "40"]
    out = _continual(capsys, data_file, second, *carry, "--frame-prior-mm", "0.3")
    assert out["updates"] == 4  # all 160 points streamed, no first model trained again
    assert out["base"]["kind"] == "geometric" and out["test"] == {}
    assert out["day_past_envelope"] < 0.05  # the same poses as the day it was trained on
    # No test set: the day's own check is each batch scored before it was learned
    rows = list(csv.DictReader((tmp_path / "day2.curve.csv").open()))
    learned = np.array([(int(r["n_new"]), float(r["batch_coverage_90"])) for r in rows])
    assert out["prequential"]["n_points"] == learned[:, 0].sum() == 4 * 36  # 4 of 40 held out
    pooled = np.average(learned[:, 1], weights=learned[:, 0])
    assert out["prequential"]["coverage_90"] == pytest.approx(pooled)
    assert 0.0 < pooled <= 1.0
    model = load_snapshot(second)
    assert model.base_kind == "geometric" and model.is_fitted
    out = _continual(capsys, data_file, second, *carry, "--new-setup")  # the tracker's frame free
    assert "tracker set up anew, its frame free; frames held" in out["base"]["note"]
    argv = ["continual", "--data", str(data_file), "--out", str(second), *carry]
    assert main([*argv, "--frame-prior-mm", "0"]) == 2
    assert "frame_prior_mm must be > 0" in capsys.readouterr().err


def test_a_model_or_base_of_another_robot_stops_with_one_line(data_file, tmp_path, capsys):
    from kinematics.dataset import read_dataset, write_dataset
    from kinematics.description import load_description
    from kinematics.gap.model_file import ModelFile, model_to_toml

    base = tmp_path / "ur10.toml"
    ur10 = ModelFile(description=load_description("ur10"), T_W_0=np.eye(4), effects=())
    base.write_text(model_to_toml(ur10))
    argv = ["train", "--data", str(data_file), "--out", str(tmp_path / "m.safetensors")]
    assert main([*argv, "--base", str(base)]) == 2
    [err] = capsys.readouterr().err.strip().splitlines()  # no progress bar before it
    assert err.startswith("robocal: ") and "is for robot 'ur10'" in err
    model = tmp_path / "m.safetensors"
    assert main([*argv, "--max-epochs", "2"]) == 0
    ds = read_dataset(data_file)
    fewer = tmp_path / "no_temps.parquet"
    write_dataset(type(ds)(ds.table.drop(columns=["temp_link2"]), ds.meta), fewer)
    capsys.readouterr()
    argv = ["continual", "--from", str(model), "--data", str(fewer), "--out", str(tmp_path / "x")]
    assert main(argv) == 2
    [err] = capsys.readouterr().err.strip().splitlines()
    assert err.startswith("robocal: ") and "no thermometer 'temp_link2', which the model" in err


def test_the_cli_caps_torch_threads(data_file, tmp_path, capsys):
    argv = ["evaluate", "--model", str(tmp_path / "none.safetensors"), "--data", str(data_file)]
    assert main(["--torch-threads", "0", *argv]) == 2
    assert "--torch-threads must be >= 1" in capsys.readouterr().err
    before, blas_before = torch.get_num_threads(), _blas_threads()
    try:
        main(["--torch-threads", "2", *argv])  # the model is missing: exit 2, threads set first
        assert torch.get_num_threads() == 2 and _blas_threads() == {2}
        main(["--torch-threads", "1", *argv])  # BLAS too: its idle threads spin
        assert torch.get_num_threads() == 1 and _blas_threads() == {1}
    finally:
        torch.set_num_threads(before)
        threadpool_limits(limits=max(blas_before), user_api="blas")


def _blas_threads() -> set[int]:
    """The thread counts of the BLAS libraries loaded in this process."""
    return {p["num_threads"] for p in threadpool_info() if p["user_api"] == "blas"}
