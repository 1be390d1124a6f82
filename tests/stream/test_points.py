"""Data points <-> dataset rows."""

import numpy as np
import pytest

from kinematics.errors import DatasetError
from stream.points import dataset_to_points, points_to_dataset
from wire import DataPoint


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


def test_round_trip_through_a_dataset():
    points = [point(i) for i in range(3)]
    ds = points_to_dataset(points, "ur10", T_W_0=np.eye(4))
    assert ds.meta.frame == "tracker" and np.eye(4).tolist() == ds.meta.T_W_0
    assert list(ds.table.columns[-9:-7]) == ["temp_base", "temp_ambient"]
    np.testing.assert_allclose(ds.deflection(), 1e-4, rtol=1e-6)
    assert [p.seq for p in dataset_to_points(ds)] == [0, 1, 2]
    back = dataset_to_points(ds)[2]
    assert back.q == points[2].q and back.temperatures == points[2].temperatures


def test_mixed_points_are_refused():
    with pytest.raises(DatasetError, match="seq 1"):
        points_to_dataset([point(0), point(1, frame="base")], "ur10")
    with pytest.raises(DatasetError):
        points_to_dataset([], "ur10")
