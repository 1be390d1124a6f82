"""``robocal gap`` / ``robocal calibrate`` in-process: exit codes, JSON, report files."""

import json

import pytest

from kinematics.dataset import write_dataset
from kinematics.description import load_description
from kinematics.gap.model_file import load_model_file
from sim_sources.cell import simulate
from sim_sources.scenarios import get_scenario
from stream.cli import main


@pytest.fixture(scope="module")
def backlash_file(tmp_path_factory):
    path = tmp_path_factory.mktemp("gap") / "backlash.parquet"
    write_dataset(simulate(get_scenario("backlash"), 300, 2), path)
    return path


@pytest.mark.integration
def test_gap_json_and_report(backlash_file, tmp_path, capsys):
    report = tmp_path / "report"
    assert main(["gap", "--data", str(backlash_file), "--report", str(report), "--json"]) == 0
    out = json.loads(capsys.readouterr().out)
    assert [e["effect"] for e in out["named_effects"]] == ["backlash"]
    assert out["after"]["mean_mm"] < 1.2 * out["noise_floor_mm"] < out["before"]["mean_mm"]
    text = (report / "gap.md").read_text()
    assert "### backlash" in text and "| + backlash |" in text
    assert (report / "gap_stages.png").read_bytes()[:4] == b"\x89PNG"
    assert (report / "gap_regions.png").stat().st_size > 1000
    assert (report / "gap.rrd").read_bytes()[:4] == b"RRF2"
    model = load_model_file(report / "model.toml")
    assert [e.name for e in model.effects] == ["backlash"]


@pytest.mark.integration
def test_calibrate_writes_a_loadable_model(backlash_file, tmp_path, capsys):
    out_path = tmp_path / "cal.toml"
    assert main(["calibrate", "--data", str(backlash_file), "--out", str(out_path), "--json"]) == 0
    out = json.loads(capsys.readouterr().out)
    assert len(out["kept"]) == 30 and out["residual"]["mean_mm"] > 0
    assert load_description(out_path).name == "fanuc_m900ib700"
    assert load_model_file(out_path).effects == ()
    # --prior-mm 0: plain least squares, which fits these poses no better
    argv = ["calibrate", "--data", str(backlash_file), "--prior-mm", "0", "--json"]
    assert main(argv) == 0
    free = json.loads(capsys.readouterr().out)
    assert free["residual"]["mean_mm"] <= out["residual"]["mean_mm"] * 1.01
    assert (out["prior_mm"], free["prior_mm"]) == (0.3, None)
    assert free["parameters"] != out["parameters"]


def test_bad_input_exits_2_with_one_line(backlash_file, tmp_path, capsys):
    assert main(["gap", "--data", str(backlash_file), "--robot", "ur10"]) == 2
    err = capsys.readouterr().err.strip().splitlines()[-1]
    assert err.startswith("robocal: error: dataset is of robot 'fanuc_m900ib700'")
    assert main(["calibrate", "--data", str(tmp_path / "missing.parquet")]) == 2
    assert "no such dataset file" in capsys.readouterr().err
    assert main(["calibrate", "--data", str(backlash_file), "--prior-mm", "-1"]) == 2
    assert "calibration.prior_mm must be > 0, got -1" in capsys.readouterr().err
