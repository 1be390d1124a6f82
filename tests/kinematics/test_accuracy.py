"""Uncalibrated accuracy summary of a dataset against its nominal robot model."""

from dataclasses import replace

import numpy as np
import pandas as pd
import pytest
from scipy.spatial.transform import Rotation

from kinematics.accuracy import accuracy_summary
from kinematics.dataset import Dataset, DatasetMeta, write_dataset
from kinematics.description import load_description
from kinematics.errors import DatasetError, DescriptionError
from kinematics.model import RobotModel
from kinematics.series import read_series
from kinematics.transforms import transform_from_xyz_rpy, xyz_quat_from_transform

T_W_0 = transform_from_xyz_rpy([2.0, -1.0, -1.0], [0.0, 0.0, 0.4])
T_6_S = transform_from_xyz_rpy([0.0, 0.0, 0.1], [0.0, 0.0, 0.0])


def make_dataset(errors_m: np.ndarray, angle_rad: float, frame: str = "tracker") -> Dataset:
    """UR10 points whose measured probe pose is off by ``errors_m`` (N, 3) and a rotation."""
    n = len(errors_m)
    q = np.random.default_rng(0).uniform(-2.0, 2.0, (n, 6))
    T = RobotModel(load_description("ur10").with_tool(T_6_S)).fk(q)
    axes = Rotation.random(n, random_state=1).as_rotvec()
    axes /= np.linalg.norm(axes, axis=1, keepdims=True)
    T[:, :3, :3] = Rotation.from_rotvec(angle_rad * axes).as_matrix() @ T[:, :3, :3]
    T[:, :3, 3] += errors_m
    if frame == "tracker":
        T = T_W_0[None] @ T
    xyz, quat = xyz_quat_from_transform(T)
    table = pd.DataFrame({"t": np.arange(n, dtype=float)})
    for i in range(6):
        table[f"q{i + 1}"] = q[:, i]
    for i, c in enumerate("xyz"):
        table[c] = xyz[:, i]
    for i, c in enumerate(("qx", "qy", "qz", "qw")):
        table[c] = quat[:, i]
    meta = DatasetMeta(robot="ur10", frame=frame, T_W_0=T_W_0.tolist(), T_6_S=T_6_S.tolist())
    return Dataset(table, meta)


@pytest.mark.parametrize("frame", ["tracker", "base"])
def test_known_errors_are_reported(frame):
    errors = np.zeros((100, 3))
    errors[:, 0] = np.linspace(0.0, 2e-3, 100)  # 0..2 mm along x
    s = accuracy_summary(make_dataset(errors, np.deg2rad(1 / 60), frame), load_description("ur10"))
    assert s.n == 100
    assert s.mean_mm == pytest.approx(1.0, abs=1e-9)
    assert s.max_mm == pytest.approx(2.0, abs=1e-9)
    assert s.std_mm == pytest.approx(np.std(np.linspace(0, 2, 100), ddof=1), abs=1e-9)
    assert s.p95_mm == pytest.approx(np.percentile(np.linspace(0, 2, 100), 95), abs=1e-9)
    assert s.mean_arcmin == pytest.approx(1.0, abs=1e-5)
    assert s.max_arcmin == pytest.approx(1.0, abs=1e-5)
    assert set(s.to_dict()) == {"n", "mean_mm", "std_mm", "max_mm", "p95_mm"} | {
        "mean_arcmin",
        "max_arcmin",
    }


def test_tool_from_description_when_meta_has_none():
    ds = make_dataset(np.zeros((10, 3)), 0.0, "base")
    ds = Dataset(ds.table, DatasetMeta(robot="ur10", frame="base"))
    # The shipped UR10 tool is the flange: the 0.1 m probe offset becomes the error.
    s = accuracy_summary(ds, load_description("ur10"))
    assert s.mean_mm == pytest.approx(100.0, abs=1e-6)


def summarised(path, robot=None):
    """The summary `robocal data summary` prints of a file."""
    desc, ds = read_series(path, robot)
    return accuracy_summary(ds, desc)


def test_a_series_summarised_is_checked_for_limits_and_robot(tmp_path):
    ds = make_dataset(np.full((20, 3), 1e-3), 0.0)
    path = write_dataset(ds, tmp_path / "d.parquet")
    s = summarised(path)
    assert s.mean_mm == pytest.approx(np.sqrt(3), abs=1e-9) and s.robot == "ur10"
    with pytest.raises(DescriptionError, match="unknown robot 'nope'"):
        summarised(path, robot="nope")
    # Another robot's description is refused by the one identity rule (kinematics/identity.py).
    with pytest.raises(DatasetError, match="dataset is of robot 'ur10', description is 'fanuc"):
        summarised(path, robot="fanuc_m900ib700")
    # Said to be a Fanuc, the UR10's joint angles break J2's limits: named by row and column.
    fanuc = write_dataset(
        Dataset(ds.table, replace(ds.meta, robot="fanuc_m900ib700")), tmp_path / "f.parquet"
    )
    with pytest.raises(DatasetError, match=r"row \d+, column 'q\d': .* outside the joint limits"):
        summarised(fanuc)
