"""``robocal report iso9283`` on a small simulated cube program, with and without a model, and
on a dataset without repeated poses."""

import json

import numpy as np
import pytest

from kinematics.dataset import read_dataset
from kinematics.description import load_description
from kinematics.model import RobotModel
from sim_sources.cell import write_campaign
from sim_sources.scenarios import get_scenario
from stream.cli import main


@pytest.fixture(scope="module")
def files(tmp_path_factory):
    """A 4-cycle cube dataset, a random-program campaign and a 3-epoch model trained on it."""
    tmp = tmp_path_factory.mktemp("iso")
    cube = write_campaign(get_scenario("iso9283"), 20, 0, tmp / "cube.parquet").path
    paper = write_campaign(get_scenario("paper"), 120, 1, tmp / "paper.parquet").path
    model = tmp / "model.safetensors"
    argv = ["train", "--data", str(paper), "--out", str(model), "--max-epochs", "3"]
    assert main([*argv, "--base", "nominal"]) == 0
    return cube, paper, model


def test_report_on_the_cube_before_and_after(files, tmp_path, capsys):
    cube, _, model = files
    capsys.readouterr()
    argv = ["report", "iso9283", "--data", str(cube), "--model", str(model)]
    assert main([*argv, "--out", str(tmp_path / "rep"), "--json"]) == 0
    out = json.loads(capsys.readouterr().out)
    assert out["n_rows"] == 20 and out["n_poses"] == 5
    assert [p["pose"] for p in out["poses"]] == ["P1", "P2", "P3", "P4", "P5"]
    assert all(p["n"] == 4 for p in out["poses"])
    for key in ("before", "after"):
        assert set(out[key]) == {"ap_p_max_mm", "ap_p_mean_mm", "rp_l_max_mm"}
        assert all(np.isfinite(v) for v in out[key].values())
    assert out["distance"]["poses"] == ["P2", "P4"] and out["distance"]["after"] is not None
    assert any(
        "fewer than the standard's 30 cycles at P1, P2, P3, P4, P5 (4 cycles)" in n
        for n in out["notes"]
    )
    # AP_P of P1 before compensation, recomputed here from the raw dataset
    ds = read_dataset(cube)
    rows = np.flatnonzero(np.abs(ds.q() - out["poses"][0]["q_rad"]).max(axis=1) < 1e-9)
    desc = load_description(ds.meta.robot).with_tool(np.asarray(ds.meta.T_6_S))
    p_c = RobotModel(desc).fk(ds.q()[rows[:1]])[0, :3, 3]
    p_m = ds.measured_poses_base()[rows, :3, 3]
    ap = 1e3 * np.linalg.norm(p_m.mean(axis=0) - p_c)
    assert out["poses"][0]["before"]["ap_p_mm"] == pytest.approx(ap, rel=1e-9)
    md = (tmp_path / "rep" / "iso9283.md").read_text()
    assert "| P1 | 4 |" in md and "→" in md and "AD_P" in md
    assert (tmp_path / "rep" / "iso9283.png").read_bytes()[:4] == b"\x89PNG"


def test_report_without_model_is_before_only(files, tmp_path, capsys):
    cube, _, _ = files
    capsys.readouterr()
    assert main(["report", "iso9283", "--data", str(cube), "--out", str(tmp_path), "--json"]) == 0
    out = json.loads(capsys.readouterr().out)
    assert out["after"] is None and all(p["after"] is None for p in out["poses"])
    assert out["before"]["ap_p_max_mm"] > 1.0  # the paper robot is millimetres off


def test_dataset_without_repeats_exits_2_with_one_line(files, tmp_path, capsys):
    _, paper, _ = files
    capsys.readouterr()
    assert main(["report", "iso9283", "--data", str(paper), "--out", str(tmp_path)]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1
    assert "no repeated poses among 120 rows" in err and "--scenario iso9283" in err
    assert not (tmp_path / "iso9283.md").exists()
