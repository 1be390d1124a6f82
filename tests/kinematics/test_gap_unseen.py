"""The gap workflow on robots and sensor layouts it has never seen (small version of
``bench/gap_unseen.py``): random arms from :mod:`sim_sources.unseen`, named by path."""

import json
from dataclasses import replace

import numpy as np
import pytest

from kinematics.dataset import Dataset, read_dataset, write_dataset
from kinematics.description import description_to_toml, load_description
from kinematics.effects import ThermalExpansion
from kinematics.gap.files import gap_from_files
from kinematics.gap.formed import select_terms
from kinematics.gap.model_file import load_model_file
from kinematics.gap.workflow import GapConfig
from sim_sources.unseen import UnseenSpec, write_unseen
from stream.cli import main


def _gap(spec: UnseenSpec, folder, start: str = "geometric"):
    path, desc, truth = write_unseen(spec, folder)
    result = gap_from_files(path, config=GapConfig(start=start))
    return result, desc, truth


@pytest.mark.parametrize(
    "spec, start",
    [
        (UnseenSpec(seed=2000, hidden="thermal_expansion", n_thermometers=7), "geometric"),
        (UnseenSpec(seed=2001, hidden="thermal_expansion", n_thermometers=1), "geometric"),
        (UnseenSpec(seed=1001, hidden="joint_compliance", with_secondary=False), "geometric"),
        (UnseenSpec(seed=4001, hidden="gear_periodic", n_axes=5), "geometric"),
        (UnseenSpec(seed=7001, hidden="tool_frame", n_axes=7), "nominal"),
    ],
)
def test_hidden_effect_on_an_unseen_robot_is_named(spec, start, tmp_path):
    result, desc, _ = _gap(spec, tmp_path, start)
    assert desc.name not in ("ur10", "fanuc_m900ib700")
    assert [e.effect for e in result.named if e.identified] == [spec.hidden]
    floor = result.noise_floor.mean_m * 1e3
    before, after = result.stages[0].heldout.mean_mm, result.stages[-1].heldout.mean_mm
    assert after < min(1.2 * floor, before)


def test_nothing_missing_names_nothing_and_lists_what_cannot_be_formed(tmp_path):
    spec = UnseenSpec(seed=90001, with_masses=False, n_thermometers=4)
    result, _, _ = _gap(spec, tmp_path)
    assert result.named == []
    assert [n for n, _ in result.not_formed] == ["joint_compliance"]
    assert "link masses" in result.not_formed[0][1]


def test_thermal_from_data_picks_the_heating_channels(tmp_path):
    spec = UnseenSpec(seed=2000, hidden="thermal_expansion", n_thermometers=7, magnitude=6)
    result, _, truth = _gap(spec, tmp_path)
    (effect, _), *_ = [(e, p) for e, p in result.blocks if e.name == "thermal_expansion"]
    W = np.asarray(truth["link_weights"])
    used = {(k, ch[0]) for k, ch in effect.effect.terms}
    names = truth["thermometers"]
    true = {(i + 1, names[c]) for i, c in zip(*np.nonzero(W), strict=True)}
    assert len(used & true) >= len(used) / 2  # mostly the true (link, channel) pairs
    assert all(v > 0 for v in result.model_file().effects[0].parameters.values())


def test_select_terms_refuses_noise_and_negative_growth():
    rng = np.random.default_rng(0)
    Jp = rng.normal(size=(600, 12))
    assert select_terms(Jp, rng.normal(size=600), 0, 0.01) == []
    r = -Jp[:, 3] * 0.5 + 0.05 * rng.normal(size=600)  # positive parameter on column 3
    assert select_terms(Jp, r, 0, 0.01) == [3]
    assert select_terms(Jp, -r, 0, 0.01) == []  # growth would be negative


def test_sensors_map_is_used_and_missing_columns_exit_2(tmp_path, capsys):
    spec = UnseenSpec(seed=2001, hidden="thermal_expansion", n_thermometers=3, n_axes=6)
    path, desc, truth = write_unseen(spec, tmp_path / "a")
    W = np.asarray(truth["link_weights"])
    names = truth["thermometers"]
    links = tuple(
        (names[c], tuple(int(i) + 1 for i in np.flatnonzero(W[:, c])))
        for c in range(len(names))
        if W[:, c].any()
    )
    mapped = tmp_path / "mapped.toml"
    mapped.write_text(description_to_toml(replace(desc, temperature_links=links)))
    assert load_description(mapped).temperature_links == links
    result = gap_from_files(path, mapped)
    assert [e.effect for e in result.named] == ["thermal_expansion"]
    (effect, _), *_ = [(e, p) for e, p in result.blocks if e.name == "thermal_expansion"]
    assert isinstance(effect.effect, ThermalExpansion)
    assert {k for k, _ in effect.effect.terms} <= {i for _, ls in links for i in ls}
    wrong = tmp_path / "wrong.toml"
    wrong.write_text(description_to_toml(replace(desc, temperature_links=(("nope", (1,)),))))
    assert main(["gap", "--data", str(path), "--robot", str(wrong)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err[-1:]) == 1 and "names temperature channel(s) temp_nope" in err[-1]


def test_indistinguishable_temperature_channels_exit_2(tmp_path, capsys):
    path, _, truth = write_unseen(UnseenSpec(seed=5, n_thermometers=3, n_points=200), tmp_path)
    ds = read_dataset(path)
    first = f"temp_{truth['thermometers'][0]}"
    table = ds.table.assign(temp_copy=2.0 * ds.table[first] + 1.0)
    bad = write_dataset(Dataset(table, ds.meta), tmp_path / "bad.parquet")
    assert main(["gap", "--data", str(bad)]) == 2
    err = capsys.readouterr().err.strip().splitlines()[-1]
    assert "cannot be told apart" in err and "temp_copy" in err


def test_unidentifiable_correction_is_not_named(tmp_path, capsys):
    """A gear error on a robot whose joints move over 40 degrees only: the harmonics trade off
    against the DH parameters, so the correction helps but must not be named gear_periodic."""
    spec = UnseenSpec(
        seed=4002, hidden="gear_periodic", n_axes=6, magnitude=10, n_points=300, joint_span_deg=40
    )
    path, _, _ = write_unseen(spec, tmp_path)
    assert main(["gap", "--data", str(path), "--report", str(tmp_path / "r"), "--json"]) == 0
    out = json.loads(capsys.readouterr().out)
    assert out["named_effects"] == []
    (e,) = out["unnamed_corrections"]
    assert e["effect"] == "gear_periodic" and e["inflation"] > 100
    assert e["message"].startswith(
        "a correction of this shape helps, but it is not identifiable as `gear_periodic`"
    )
    assert out["after"]["mean_mm"] < 0.6 * out["before"]["mean_mm"]  # it still helps
    model = load_model_file(tmp_path / "r" / "model.toml")
    assert [(m.name, m.identified) for m in model.effects] == [("gear_periodic", False)]
    assert "not identifiable as `gear_periodic`" in (tmp_path / "r" / "gap.md").read_text()
