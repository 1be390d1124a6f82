import numpy as np
import pytest

from kinematics.errors import SnapshotError
from learner.config import ModelConfig, TrainConfig
from learner.features import FeatureSpec
from learner.model import ErrorModel
from learner.snapshot import (
    load_snapshot,
    save_snapshot,
    snapshot_from_bytes,
    snapshot_meta,
    snapshot_to_bytes,
)

SPEC = FeatureSpec(
    names=("q1", "q2", "temp_a"), low=np.array([-3.0, -2, 0]), high=np.array([3.0, 2, 60])
)


@pytest.fixture(scope="module")
def trained():
    rng = np.random.default_rng(0)
    X = rng.uniform(SPEC.low, SPEC.high, (120, 3))
    Y = 1e-3 * np.sin(X[:, :1] + np.arange(6)) + rng.normal(0, 1e-5, (120, 6))
    m = ErrorModel.create(
        SPEC,
        ModelConfig(hidden_layers=2, neurons=16, dropout=0.1, encoding="minmax"),
        TrainConfig(max_epochs=5),
        3,
        robot="ur10",
    )
    m.fit(X, Y)
    m.metrics = {"mean_mm": 0.5}
    return m, X


def test_reload_predicts_bit_identically(trained, tmp_path):
    m, X = trained
    path = save_snapshot(m, tmp_path / "m.safetensors")
    back = load_snapshot(path)
    a, b = m.predict(X), back.predict(X)
    for field in ("gamma", "nu", "alpha", "beta"):
        np.testing.assert_array_equal(getattr(a, field), getattr(b, field))
    assert back.feature_names == m.feature_names and back.robot == "ur10"
    assert back.model_cfg == m.model_cfg and back.train_cfg == m.train_cfg
    assert back.metrics == {"mean_mm": 0.5}
    np.testing.assert_array_equal(back.spec.low, SPEC.low)


def test_metadata_is_json_and_no_pickle(trained):
    m, _ = trained
    data = snapshot_to_bytes(m, extra_meta={"version": 7})
    meta = snapshot_meta(data)
    assert meta["schema"] == "robocal.model" and meta["extra"] == {"version": 7}
    assert meta["feature_names"] == ["q1", "q2", "temp_a"]
    assert b"pickle" not in data and not data.startswith(b"\x80")


def test_bad_snapshots_raise(trained, tmp_path):
    m, _ = trained
    data = snapshot_to_bytes(m)
    with pytest.raises(SnapshotError, match="no such"):
        load_snapshot(tmp_path / "missing.safetensors")
    (tmp_path / "junk.safetensors").write_bytes(b"\x05\x00\x00\x00\x00\x00\x00\x00junk!")
    with pytest.raises(SnapshotError, match="junk.safetensors"):
        load_snapshot(tmp_path / "junk.safetensors")
    with pytest.raises(SnapshotError):
        snapshot_from_bytes(data[: len(data) // 2])
    other = ErrorModel.create(
        SPEC, ModelConfig(hidden_layers=1, neurons=4, encoding="minmax"), TrainConfig(), 0
    )
    blob = snapshot_to_bytes(other)
    swapped = blob.replace(b'\\"hidden_layers\\": 1', b'\\"hidden_layers\\": 2')
    assert swapped != blob
    with pytest.raises(SnapshotError, match="does not match"):
        snapshot_from_bytes(swapped)


def test_kinematic_model_reloads_bit_identically_with_its_tool(tmp_path):
    from kinematics.description import load_description
    from learner.features import feature_spec

    tool = np.array([[0, -1, 0, 0.02], [1, 0, 0, 0.01], [0, 0, 1, 0.3], [0, 0, 0, 1.0]])
    desc = load_description("ur10").with_tool(tool)
    spec = feature_spec(desc, n_temperatures=1, has_secondary=True)
    rng = np.random.default_rng(1)
    X = np.hstack(
        [rng.uniform(-3, 3, (80, 6)), rng.normal(0, 1e-4, (80, 6)), rng.uniform(15, 40, (80, 1))]
    )
    Y = 1e-3 * np.sin(X[:, :1] + np.arange(6))
    m = ErrorModel.create(
        spec, ModelConfig(hidden_layers=1, neurons=8, members=2), TrainConfig(max_epochs=3), 0
    )
    m.fit(X, Y)
    back = load_snapshot(save_snapshot(m, tmp_path / "k.safetensors"))
    assert back.model_cfg.encoding == "kinematic" and back.model_cfg.members == 2
    np.testing.assert_array_equal(back.spec.description.tool, tool)
    np.testing.assert_array_equal(back.predict(X).gamma, m.predict(X).gamma)
    np.testing.assert_array_equal(back.predict(X).beta, m.predict(X).beta)


def test_version_1_snapshots_load_as_minmax(trained):
    import json

    from safetensors.torch import load as st_load
    from safetensors.torch import save as st_save

    _, X = trained
    cfg = ModelConfig(hidden_layers=1, neurons=8, members=1, encoding="minmax")
    m = ErrorModel.create(SPEC, cfg, TrainConfig(max_epochs=3), 0)
    m.fit(X, 1e-3 * np.sin(X[:, :1] + np.arange(6)))
    data = snapshot_to_bytes(m)
    meta = snapshot_meta(data)
    meta["version"] = 1
    del meta["description"], meta["model_config"]["encoding"], meta["model_config"]["members"]
    old = st_save(st_load(data), metadata={"robocal": json.dumps(meta)})
    back = snapshot_from_bytes(old)
    assert back.model_cfg.encoding == "minmax" and back.model_cfg.members == 1
    np.testing.assert_array_equal(back.predict(X).gamma, m.predict(X).gamma)


def test_a_snapshot_from_before_the_variance_power_goes_on_with_the_plain_nll(trained):
    import json

    from safetensors.torch import load as st_load
    from safetensors.torch import save as st_save

    m, X = trained
    data = snapshot_to_bytes(m)
    assert (
        snapshot_meta(data)["train_config"]["nll_variance_power"]
        == TrainConfig().nll_variance_power
        > 0
    )
    meta = snapshot_meta(data)
    del meta["train_config"]["nll_variance_power"]
    back = snapshot_from_bytes(st_save(st_load(data), metadata={"robocal": json.dumps(meta)}))
    assert back.train_cfg.nll_variance_power == 0.0  # as it was trained
    np.testing.assert_array_equal(back.predict(X).gamma, m.predict(X).gamma)


@pytest.mark.parametrize(
    ("value", "error"),
    [
        ("the frames moved on this day (30 points)", None),
        (None, None),
        ({"a": [1]}, "dict"),
        (12, "int"),
    ],
)
def test_unverified_is_a_reason_or_nothing(trained, value, error):
    """A snapshot's ``unverified``: a string is the reason, null or absent is verified, anything
    else is a one-line SnapshotError (not a reason that reads ``{'a': [1]}``)."""
    import json

    from safetensors.torch import load as st_load
    from safetensors.torch import save as st_save

    m, _ = trained
    data = snapshot_to_bytes(m)
    meta = snapshot_meta(data)
    meta["unverified"] = value
    blob = st_save(st_load(data), metadata={"robocal": json.dumps(meta)})
    if error is None:
        assert snapshot_from_bytes(blob).unverified == (value or "")
    else:
        with pytest.raises(SnapshotError, match=f"unverified must be a string, got {error}"):
            snapshot_from_bytes(blob)
    del meta["unverified"]
    old = st_save(st_load(data), metadata={"robocal": json.dumps(meta)})
    assert snapshot_from_bytes(old).unverified == ""
