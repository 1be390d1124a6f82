import numpy as np
import pytest

from kinematics.description import load_description
from kinematics.errors import ConfigError, DatasetError
from kinematics.model import RobotModel
from kinematics.transforms import pose_error
from learner.features import (
    FeatureSpec,
    dataset_feature_spec,
    dataset_features,
    dataset_labels,
    feature_spec,
    features,
    labels,
)
from tests.learner.conftest import make_dataset

FANUC = load_description("fanuc_m900ib700")


def test_full_spec_ranges_come_from_the_description():
    spec = feature_spec(FANUC, 2, True, ("link2", "temp_link4"))
    assert spec.names[:7] == ("q1", "q2", "q3", "q4", "q5", "q6", "dtheta1")
    assert spec.names[-2:] == ("temp_link2", "temp_link4")
    np.testing.assert_allclose(spec.low[:6], FANUC.limits_rad[:, 0])
    np.testing.assert_allclose(spec.high[6:12], FANUC.sensors.deflection_max_rad)
    assert spec.high[-1] == FANUC.sensors.temperature_max_c


@pytest.mark.parametrize(
    "secondary, temperatures, n",
    [(True, True, 14), (True, False, 12), (False, True, 8), (False, False, 6)],
)
def test_feature_subsets(small_ds, secondary, temperatures, n):
    spec = dataset_feature_spec(small_ds, FANUC, secondary=secondary, temperatures=temperatures)
    X = dataset_features(small_ds, spec)
    assert X.shape == (len(small_ds), n) == (len(small_ds), spec.n_features)
    np.testing.assert_array_equal(X[:, :6], small_ds.q())
    if secondary:
        np.testing.assert_allclose(X[:, 6:12], small_ds.deflection())


def test_one_thermometer_and_no_secondary(small_ds):
    ds = small_ds.subset(np.arange(20))
    ds.table = ds.table.drop(columns=[f"qs{i}" for i in range(1, 7)] + ["temp_link4"])
    spec = dataset_feature_spec(ds, FANUC)
    assert spec.names == ("q1", "q2", "q3", "q4", "q5", "q6", "temp_link2")
    assert dataset_features(ds, spec).shape == (20, 7)


def test_scaling_is_fixed_by_ranges_not_data(small_ds):
    spec = dataset_feature_spec(small_ds, FANUC)
    X = dataset_features(small_ds, spec)
    a = spec.scale(X[:10])
    b = spec.scale(X)[:10]
    np.testing.assert_array_equal(a, b)
    assert np.all(np.abs(spec.scale(X)) <= 1.0)


def test_labels_are_the_pose_error_against_nominal_fk(small_ds):
    model = RobotModel(FANUC)
    Y = dataset_labels(small_ds, model)
    want = pose_error(small_ds.measured_poses_base(), model.fk(small_ds.q()))
    np.testing.assert_array_equal(Y, want)
    assert 0.5e-3 < np.linalg.norm(Y[:, :3], axis=1).mean() < 20e-3


def test_missing_column_and_bad_spec_raise(small_ds):
    spec = feature_spec(FANUC, 1, False, ("cabinet",))
    with pytest.raises(DatasetError, match="temp_cabinet"):
        dataset_features(small_ds, spec)
    with pytest.raises(ConfigError, match="name 2"):
        feature_spec(FANUC, 2, False, ("a",))
    with pytest.raises(DatasetError, match=r"shape \(N, 7\)"):
        spec.scale(np.zeros((3, 6)))


def test_one_builder_from_arrays(small_ds):
    spec = dataset_feature_spec(small_ds, FANUC)
    temps = small_ds.temperatures()
    by_channel = {"link2": temps[:, 0], "temp_link4": temps[:, 1]}  # channel or column names
    X = features(spec, small_ds.q(), small_ds.deflection(), by_channel)
    assert X.tobytes() == dataset_features(small_ds, spec).tobytes()
    model = RobotModel(FANUC)
    Y = labels(model, small_ds.q(), small_ds.measured_poses_base())
    assert Y.tobytes() == dataset_labels(small_ds, model).tobytes()
    one = features(spec, small_ds.q()[:1], np.zeros((1, 6)), {"link2": 30, "link4": 31.5})
    assert one[0, 6:].tolist() == [0.0] * 6 + [30.0, 31.5]  # one value per channel, deflection 0
    odd = FeatureSpec(names=("temp_link4", "q2", "dtheta1", "q1"), low=np.zeros(4), high=[1] * 4)
    X = features(odd, small_ds.q(), small_ds.deflection(), by_channel)  # any order of names
    want = [temps[:, 1], small_ds.q()[:, 1], small_ds.deflection()[:, 0], small_ds.q()[:, 0]]
    assert X.tobytes() == np.stack(want, axis=1).tobytes()


def test_builder_names_what_is_missing(small_ds):
    spec = dataset_feature_spec(small_ds, FANUC)
    q = small_ds.q()
    with pytest.raises(DatasetError, match="qs1"):
        features(spec, q, None, {"link2": 20.0, "link4": 20.0})
    with pytest.raises(DatasetError, match="temp_link4"):
        features(spec, q, q * 0, {"link2": 20.0})
    with pytest.raises(DatasetError, match="q6"):
        features(spec, q[:, :5], q * 0, {"link2": 20.0, "link4": 20.0})
    odd = FeatureSpec(names=("q1", "speed"), low=np.zeros(2), high=np.ones(2))
    with pytest.raises(DatasetError, match="unknown feature 'speed'"):
        features(odd, q, None, None)
    with pytest.raises(DatasetError, match="all be single values or all arrays"):
        features(spec, q, q * 0, {"link2": 20.0, "link4": q[:, 0]})


def test_synthetic_dataset_is_seeded():
    a, b = make_dataset(5, seed=3), make_dataset(5, seed=3)
    assert a.table.equals(b.table)
