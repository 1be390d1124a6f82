"""Scenarios by name, with magnitudes drawn from the robot seed and scaled."""

import numpy as np
import pytest

from kinematics.description import load_description
from kinematics.effects import EFFECTS
from kinematics.errors import ConfigError, DescriptionError
from sim_sources.scenarios import SCENARIOS, get_scenario, list_scenarios, true_parameters

FANUC = load_description("fanuc_m900ib700")


def test_paper_nominal_and_one_scenario_per_effect():
    assert {"paper", "nominal", "iso9283", *EFFECTS} == set(SCENARIOS) == set(list_scenarios())
    assert set(SCENARIOS["paper"].effects) == set(EFFECTS)
    assert SCENARIOS["iso9283"].effects == SCENARIOS["paper"].effects
    assert SCENARIOS["iso9283"].program.kind == "iso9283"
    assert SCENARIOS["nominal"].effects == () and not SCENARIOS["nominal"].noise
    for name in EFFECTS:
        assert SCENARIOS[name].effects == (name,)


def test_single_effect_robots_share_the_paper_robot():
    paper = dict((e.name, p) for e, p in get_scenario("paper").build_effects(FANUC))
    for name in EFFECTS:
        ((effect, params),) = get_scenario(name).build_effects(FANUC)
        np.testing.assert_array_equal(params, paper[name])


def test_scale_multiplies_every_magnitude():
    one = true_parameters(get_scenario("paper"), FANUC)
    half = true_parameters(get_scenario("paper", scale=0.5), FANUC)
    for name in one:
        np.testing.assert_allclose(half[name], 0.5 * one[name])
    assert all(
        not np.any(p) for p in true_parameters(get_scenario("paper", scale=0.0), FANUC).values()
    )


def test_magnitudes_are_physically_plausible():
    p = true_parameters(get_scenario("paper"), FANUC)
    dh = p["geometric"].reshape(6, 5)
    assert np.abs(dh[:, :2]).max() < 1e-3 and np.abs(dh[:, 2:]).max() < np.deg2rad(0.05)
    stiffness = 1 / p["joint_compliance"]
    assert np.all((stiffness >= 1e6) & (stiffness <= 1e8))
    np.testing.assert_allclose(p["thermal_expansion"], 11.5e-6)
    assert np.all(p["backlash"] < np.deg2rad(3 / 60))


def test_unknown_names_raise_one_line():
    with pytest.raises(ConfigError, match="unknown scenario 'x'; known: paper"):
        get_scenario("x")
    with pytest.raises(ConfigError, match="scale must be >= 0"):
        get_scenario("paper", scale=-1.0)


def test_a_gap_model_file_runs_in_the_simulator(tmp_path):
    """The model `robocal gap` writes (description + identified effects) is a simulated robot."""
    from kinematics.gap.model_file import EffectEntry, ModelFile, model_to_toml
    from sim_sources.cell import simulate
    from sim_sources.scenarios import scenario_from_model

    reference = get_scenario("joint_compliance", noise=False)
    desc = load_description(reference.robot)
    ((effect, params),) = reference.build_effects(desc)
    entry = EffectEntry(
        name=effect.name,
        options=effect.options(),
        parameters=dict(zip(effect.parameter_names(desc), map(float, params), strict=True)),
        std={},
    )
    path = tmp_path / "model.toml"
    path.write_text(model_to_toml(ModelFile(description=desc, T_W_0=np.eye(4), effects=(entry,))))
    from_model = simulate(scenario_from_model(str(path), reference), 40, 5)
    direct = simulate(reference, 40, 5)
    cols = ["x", "y", "z", "qx", "qy", "qz", "qw", "qs2", "qs3"]
    np.testing.assert_allclose(from_model.table[cols], direct.table[cols], atol=1e-12)
    assert from_model.meta.robot == str(path)
    with pytest.raises(DescriptionError, match="cannot read model file"):
        scenario_from_model(str(tmp_path / "missing.toml"))
