"""The simulated cell end to end: zero error without effects, effects where physics puts them,
secondary encoders, noise floor, byte-identical files, the paper campaign's statistics."""

import json
from dataclasses import replace

import numpy as np
import pytest

from kinematics.dataset import read_dataset, temperature_columns
from kinematics.description import load_description
from kinematics.effects import EFFECTS
from kinematics.model import RobotModel
from kinematics.transforms import pose_error
from sim_sources.cell import SimulatedCell, simulate, uncalibrated_accuracy, write_campaign
from sim_sources.scenarios import get_scenario

FANUC = RobotModel(load_description("fanuc_m900ib700"))


def errors(ds) -> np.ndarray:
    """Position errors (N, 3) m of the measured poses against the nominal FK, base frame."""
    return pose_error(ds.measured_poses_base(), FANUC.fk(ds.q()))[:, :3]


@pytest.fixture(scope="module")
def paper():
    return simulate(get_scenario("paper"), 3004, 0)


def test_no_effect_and_no_noise_means_zero_error():
    ds = simulate(get_scenario("nominal"), 200, 0)
    assert np.abs(errors(ds)).max() < 1e-9
    np.testing.assert_array_equal(ds.deflection(), 0.0)
    assert ds.meta.noise_floor_m == 0.0


@pytest.mark.parametrize("name", list(EFFECTS))
def test_each_effect_alone_is_all_of_the_error(name):
    ds = simulate(get_scenario(name, noise=False), 64, 1)
    t = ds.table
    total = errors(ds)
    own = t[[f"true_{name}_dx", f"true_{name}_dy", f"true_{name}_dz"]].to_numpy()
    np.testing.assert_allclose(total, own, atol=1e-12)
    np.testing.assert_allclose(total, t[["true_ex", "true_ey", "true_ez"]].to_numpy(), atol=1e-12)
    assert np.linalg.norm(total, axis=1).mean() > 1e-7  # drift is small after minutes


def test_compliance_sags_and_secondary_encoders_see_it():
    ds = simulate(get_scenario("joint_compliance", noise=False), 200, 2)
    assert errors(ds)[:, 2].mean() < -1e-4
    dtheta = ds.deflection()
    assert np.abs(dtheta[:, 1:3]).max() > 1e-5
    cell = SimulatedCell(get_scenario("joint_compliance", noise=False), 200, 2)
    cond = cell.conditions()
    np.testing.assert_allclose(dtheta, cell.truth.deflection(cond), atol=1e-15)
    heavier = replace(cond, payload_kg=cond.payload_kg + 700.0)
    extra = cell.truth.poses(heavier)[:, 2, 3] - cell.truth.poses(cond)[:, 2, 3]
    assert np.mean(extra < 0) > 0.95
    extra_dtheta = cell.truth.deflection(heavier) - cell.truth.deflection(cond)
    assert np.abs(extra_dtheta[:, 1]).mean() > 1e-5


def test_drift_error_grows_with_time():
    ds = simulate(get_scenario("tracker_drift", noise=False), 300, 0)
    norm = np.linalg.norm(errors(ds), axis=1)
    t = ds.table["t"].to_numpy()
    assert np.corrcoef(t, norm)[0, 1] > 0.9


def test_heat_grows_the_reach():
    ds = simulate(get_scenario("thermal_expansion", noise=False), 300, 0)
    nominal = FANUC.fk(ds.q())[:, :3, 3]
    radial = np.einsum("ni,ni->n", errors(ds), nominal / np.linalg.norm(nominal, axis=1)[:, None])
    hot = ds.table["temp_lower_arm"].to_numpy() - 20.0
    assert np.corrcoef(hot, radial)[0, 1] > 0.5 and radial[hot > 10].mean() > 0


def test_backlash_error_flips_with_the_approach():
    cell = SimulatedCell(get_scenario("backlash", noise=False), 64, 0)
    cond = cell.conditions()
    nominal = FANUC.fk(cond.q)[:, :3, 3]
    up = cell.truth.poses(cond)[:, :3, 3] - nominal
    down = cell.truth.poses(replace(cond, approach=-cond.approach))[:, :3, 3] - nominal
    assert np.linalg.norm(up, axis=1).mean() > 5e-5
    np.testing.assert_allclose(up, -down, atol=1e-5)


def test_noise_floor_is_the_measured_noise(paper):
    assert 15e-6 < paper.meta.noise_floor_m < 80e-6
    quiet = simulate(get_scenario("paper", noise=False), 100, 0)
    noisy = simulate(get_scenario("paper"), 100, 0)
    diff = np.linalg.norm(errors(noisy) - errors(quiet), axis=1)
    assert diff.mean() == pytest.approx(noisy.meta.noise_floor_m, rel=1e-6)


def test_dataset_format_and_metadata(paper, tmp_path):
    t = paper.table
    assert len(temperature_columns(t)) == 15 and "temp_ambient" in t.columns
    assert [f"qs{i}" for i in range(1, 7)] == [c for c in t.columns if c.startswith("qs")]
    meta = paper.meta
    assert meta.frame == "tracker" and meta.robot == "fanuc_m900ib700"
    assert meta.extra["scenario"] == "paper" and meta.extra["seed"] == 0
    assert set(meta.extra["effects"]) == set(EFFECTS)
    assert meta.extra["effects"]["joint_compliance"]["c2_rad_per_Nm"] > 0
    assert meta.extra["effect_options"]["backlash"] == {"sign_from": "approach"}
    path = tmp_path / "paper.csv"
    report = write_campaign(get_scenario("paper"), 50, 4, path)
    back = read_dataset(path, limits_rad=FANUC.description.limits_rad)
    assert len(back) == report.n == 50
    assert json.loads(path.with_suffix(".meta.json").read_text())["extra"]["seed"] == 4


@pytest.mark.parametrize("suffix", [".parquet", ".csv"])
def test_same_seed_same_bytes(tmp_path, suffix):
    paths = [tmp_path / f"a{suffix}", tmp_path / f"b{suffix}", tmp_path / f"c{suffix}"]
    for path, seed in zip(paths, (7, 7, 8), strict=True):
        write_campaign(get_scenario("paper"), 120, seed, path)
    a, b, c = (p.read_bytes() for p in paths)
    assert a == b and a != c
    assert (
        paths[0].with_suffix(".meta.json").read_bytes()
        == paths[1].with_suffix(".meta.json").read_bytes()
    )


def test_paper_campaign_matches_the_published_accuracy(paper):
    acc = uncalibrated_accuracy(paper)
    assert acc.n == 3004
    assert acc.mean_mm == pytest.approx(2.77, rel=0.15)
    assert acc.std_mm == pytest.approx(0.84, rel=0.15)
    assert acc.max_mm == pytest.approx(10.25, rel=0.15)


def test_secondary_encoders_see_backlash_flip_with_approach():
    ds = simulate(get_scenario("backlash", noise=False), 200, 3)
    dtheta = ds.deflection()
    approach = ds.table[[f"true_approach{i}" for i in range(1, 7)]].to_numpy()
    # The link lags the motor: the arm-side reading is behind the approach direction.
    assert np.all(np.sign(dtheta[:, 0]) == -approach[:, 0])
    assert np.abs(dtheta).max() < 1e-3
