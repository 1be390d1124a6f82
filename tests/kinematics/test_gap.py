"""The gap workflow on simulated hidden-effect data (fixed seeds): names, shrink, honesty."""

import json

import numpy as np
import pytest

from kinematics.calibration import CalibrationConfig, GeometricFrames, identify
from kinematics.description import load_description
from kinematics.effects import EFFECTS, perturbed_poses
from kinematics.errors import ConfigError, DescriptionError, IdentifiabilityError
from kinematics.gap.candidates import FitState, make_effect, score_candidate
from kinematics.gap.model_file import load_model_file, model_to_toml
from kinematics.gap.workflow import GapConfig, run_gap, split
from kinematics.identification.conditions import (
    cell_description,
    infer_approach,
    observations_from_dataset,
)
from kinematics.identification.fitting import fit_effects
from kinematics.model import RobotModel
from sim_sources.cell import simulate
from sim_sources.scenarios import get_scenario

N = 400


def sim(name, scale=1.0, seed=0, n=N):
    return simulate(get_scenario(name, scale=scale), n, seed)


def gap(ds, **kw):
    return run_gap(load_description(ds.meta.robot), ds, GapConfig(**kw))


@pytest.fixture(scope="module")
def compliance_result():
    ds = sim("joint_compliance", seed=3)
    return ds, gap(ds)


def test_hidden_compliance_is_named_and_the_gap_shrinks(compliance_result):
    ds, result = compliance_result
    assert [e.effect for e in result.named] == ["joint_compliance"]
    floor_mm = ds.meta.noise_floor_m * 1e3
    before, after = result.stages[0].heldout, result.stages[-1].heldout
    assert before.mean_mm > 5 * floor_mm
    assert after.mean_mm < 1.2 * floor_mm
    assert result.consistent_with_floor
    evidence = result.named[0].evidence
    assert evidence.p_holm < 1e-6 and evidence.delta_bic < 0 and evidence.explained_share > 0.9
    # The identified compliances of the well-excited main axes match the truth within 4 sigma.
    truth = ds.meta.extra["effects"]["joint_compliance"]
    named = result.named[0]
    for key in ("c2_rad_per_Nm", "c3_rad_per_Nm"):
        assert abs(named.parameters[key] - truth[key]) < 4 * named.std[key] + 0.05 * truth[key]


def test_json_contract(compliance_result):
    _, result = compliance_result
    out = json.loads(json.dumps(result.to_dict()))
    assert {"disagreement", "named_effects", "before", "after", "noise_floor_mm"} <= out.keys()
    assert out["named_effects"][0]["effect"] == "joint_compliance"
    assert out["disagreement"] and all(r["significant"] for r in out["disagreement"])
    assert out["after"]["mean_mm"] < out["before"]["mean_mm"]


def test_model_file_runs_in_the_simulator_math(compliance_result, tmp_path):
    ds, result = compliance_result
    path = tmp_path / "model.toml"
    path.write_text(model_to_toml(result.model_file()))
    model = load_model_file(path)
    assert [e.name for e in model.effects] == ["joint_compliance"]
    assert load_description(path).name == ds.meta.robot
    desc = model.description
    obs = observations_from_dataset(ds, desc)
    T = model.T_W_0[None] @ perturbed_poses(RobotModel(desc), obs.cond, model.blocks())
    err = np.linalg.norm(T[:, :3, 3] - obs.T_measured[:, :3, 3], axis=1)
    assert err.mean() < 1.3 * ds.meta.noise_floor_m


@pytest.mark.parametrize(
    "scenario, start, expected",
    [("backlash", "geometric", "backlash"), ("base_frame", "nominal", "base_frame")],
)
def test_other_hidden_effects_are_named(scenario, start, expected):
    ds = sim(scenario, seed=5)
    result = gap(ds, start=start)
    assert [e.effect for e in result.named] == [expected]
    assert result.stages[-1].heldout.mean_mm < 1.2 * ds.meta.noise_floor_m * 1e3


def test_nothing_missing_names_nothing():
    ds = sim("geometric", seed=4)
    result = gap(ds)
    assert result.named == []
    assert result.to_dict()["named_effects"] == []
    assert result.consistent_with_floor


def test_indistinguishable_candidate_is_reported_not_guessed():
    ds = sim("geometric", seed=4, n=150)
    desc = cell_description(load_description(ds.meta.robot), ds)
    model, obs = RobotModel(desc), observations_from_dataset(ds, desc)
    geo = GeometricFrames(desc, identify(model, obs, CalibrationConfig()).kept_index)
    fit = fit_effects(model, obs, [(geo, np.zeros(len(geo.free)))])
    r = np.concatenate([fit.residual[:, :3], fit.rotation_weight_m * fit.residual[:, 3:]], 1)
    blocks = fit.blocks([geo])
    state = FitState(blocks, fit.jac, r.ravel(), fit.rotation_weight_m)
    score = score_candidate(EFFECTS["tool_frame"](), model, obs, state)
    assert score.kept == () and not score.significant
    assert "cannot be told apart" in score.note and len(score.absorbed) == 6


def test_candidate_without_its_data_is_not_testable():
    ds = sim("geometric", seed=4, n=60)
    table = ds.table.drop(columns=[c for c in ds.table.columns if c.startswith("temp_")])
    ds = type(ds)(table, ds.meta)
    desc = cell_description(load_description(ds.meta.robot), ds)
    model, obs = RobotModel(desc), observations_from_dataset(ds, desc)
    state = FitState([], np.zeros((6 * 60, 0)), np.ones(360), 1.0)
    score = score_candidate(make_effect("thermal_expansion"), model, obs, state)
    assert score.note.startswith("not testable") and "temperatures" in score.note


def test_too_few_points_for_the_start_raise():
    ds = sim("geometric", seed=4, n=30)
    with pytest.raises(IdentifiabilityError, match="needs at least"):
        gap(ds)


def test_split_is_seeded_and_disjoint():
    a, b = split(100, 0.2, 3)
    assert len(b) == 20 and not set(a) & set(b)
    assert np.array_equal(split(100, 0.2, 3)[1], b)


def test_infer_approach_and_config_validation():
    q = np.array([[0.0, 1.0], [0.5, 0.5], [0.2, 0.9]])
    assert infer_approach(q).tolist() == [[1, -1], [1, -1], [-1, 1]]
    with pytest.raises(ConfigError, match="gap.start"):
        GapConfig(start="perfect")
    with pytest.raises(ConfigError, match="unknown effect"):
        make_effect("wobble")


def test_model_file_with_a_missing_parameter_is_rejected(compliance_result, tmp_path):
    _, result = compliance_result
    text = model_to_toml(result.model_file())
    path = tmp_path / "broken.toml"
    path.write_text(text.replace("c1_rad_per_Nm = ", "c1_typo = "))
    with pytest.raises(DescriptionError, match="missing parameter"):
        load_model_file(path)
