"""Data points -> arrays -> the learner's feature builder: bit for bit the features and labels
training builds from the same readings in a dataset."""

import dataclasses

import numpy as np
import pytest

from kinematics.dataset import (
    POSE_COLUMNS,
    secondary_columns,
    temperature_columns,
    temperature_name,
)
from kinematics.description import load_description
from kinematics.errors import DatasetError
from kinematics.model import RobotModel
from learner.features import dataset_feature_spec, dataset_features, dataset_labels
from sim_sources.cell import simulate
from sim_sources.scenarios import get_scenario
from stream.points import dataset_to_points, point_arrays
from wire import DataPoint, decode, encode


def point(seq, **kw):
    base = dict(
        seq=seq,
        t=float(seq),
        q=(0.1 * seq,) * 6,
        qs=(0.1 * seq + 1e-4,) * 6,
        xyz=(1.0, 0.0, 0.5),
        quat=(0.0, 0.0, 0.0, 1.0),
        frame="tracker",
        temperature_names=("base", "ambient"),
        temperatures=(25.0, 20.0),
    )
    return DataPoint(**{**base, **kw})


def wire_points(ds):
    """The dataset's rows as data points that went over the wire, with the table's own
    secondary encoder readings (what a cell sends, not ``q + (qs - q)``)."""
    t = ds.table
    temps = temperature_columns(t)
    qs = secondary_columns(t)
    points = []
    for i, row in enumerate(t.itertuples(index=False)):
        r = row._asdict()
        p = DataPoint(
            seq=i,
            t=r["t"],
            q=tuple(r[f"q{j}"] for j in range(1, 7)),
            qs=tuple(r[c] for c in qs) if qs else None,
            xyz=tuple(r[c] for c in POSE_COLUMNS[:3]),
            quat=tuple(r[c] for c in POSE_COLUMNS[3:]),
            frame=ds.meta.frame,
            temperature_names=tuple(temperature_name(c) for c in temps),
            temperatures=tuple(r[c] for c in temps),
        )
        points.append(decode(encode(p), DataPoint))
    return points


@pytest.fixture(scope="module")
def campaign():
    return simulate(get_scenario("paper"), 40, 3)  # tracker frame, qs, 15 thermometers


@pytest.mark.parametrize("secondary, temperatures", [(True, True), (False, True), (True, False)])
def test_stream_features_and_labels_are_bit_identical_to_training(
    campaign, secondary, temperatures
):
    ds = campaign
    desc = load_description(ds.meta.robot)
    spec = dataset_feature_spec(ds, desc, secondary=secondary, temperatures=temperatures)
    arrays = point_arrays(wire_points(ds), np.asarray(ds.meta.T_W_0))
    X, want = arrays.features(spec), dataset_features(ds, spec)
    assert X.shape == want.shape and X.dtype == want.dtype and X.tobytes() == want.tobytes()
    robot = RobotModel(desc)
    assert arrays.labels(robot).tobytes() == dataset_labels(ds, robot).tobytes()


def test_base_frame_points_without_secondary_or_thermometers(campaign):
    ds = campaign.subset(np.arange(10))
    ds.table = ds.table.drop(columns=secondary_columns(ds.table) + temperature_columns(ds.table))
    ds = dataclasses.replace(ds, meta=dataclasses.replace(ds.meta, frame="base"))
    arrays = point_arrays(wire_points(ds))
    assert arrays.deflection is None and arrays.temperatures.shape == (10, 0)
    spec = dataset_feature_spec(ds, load_description(ds.meta.robot))
    assert arrays.features(spec).tobytes() == dataset_features(ds, spec).tobytes()


def test_arrays_of_points():
    points = [point(i) for i in range(3)]
    a = point_arrays(points, T_W_0=np.eye(4))
    assert a.temperature_names == ("base", "ambient") and a.temperatures[2].tolist() == [25, 20]
    np.testing.assert_allclose(a.deflection, 1e-4, rtol=1e-6)
    np.testing.assert_array_equal(a.T_0_S[:, :3, 3], [[1.0, 0.0, 0.5]] * 3)
    # a later point without the first point's secondary encoders reads NaN (refused downstream)
    lacking = point_arrays([point(0), point(1, qs=None)], T_W_0=np.eye(4))
    assert np.isnan(lacking.deflection[1]).all() and np.isfinite(lacking.deflection[0]).all()


def test_mixed_points_are_refused():
    with pytest.raises(DatasetError, match="seq 1"):
        point_arrays([point(0), point(1, frame="base")], np.eye(4))
    with pytest.raises(DatasetError, match="seq 1"):
        point_arrays([point(0), point(1, temperature_names=("base", "cabinet"))], np.eye(4))
    with pytest.raises(DatasetError, match="T_W_0"):
        point_arrays([point(0)])
    with pytest.raises(DatasetError):
        point_arrays([])


def test_dataset_rows_become_points(campaign):
    ds = campaign.subset(np.arange(3))
    back = dataset_to_points(ds)
    assert [p.seq for p in back] == [0, 1, 2] and "ambient" in back[2].temperature_names
    assert back[2].q == tuple(ds.q()[2]) and len(back[2].temperatures) == 15
