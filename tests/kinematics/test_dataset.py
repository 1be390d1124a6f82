"""The dataset format: exact round trips, one-line errors naming row and column, atomic writes."""

import json

import numpy as np
import pandas as pd
import pytest

from kinematics.dataset import (
    Dataset,
    DatasetMeta,
    meta_path,
    poses_in_base,
    read_dataset,
    temperature_column,
    temperature_columns,
    temperature_name,
    validate,
    write_dataset,
)
from kinematics.description import load_description
from kinematics.errors import DatasetError
from kinematics.transforms import transform_from_xyz_rpy, xyz_quat_from_transform


def make(n: int = 25, seed: int = 0) -> Dataset:
    rng = np.random.default_rng(seed)
    table = pd.DataFrame({"t": np.cumsum(rng.uniform(0.1, 1.0, n))})
    for i in range(1, 7):
        table[f"q{i}"] = rng.uniform(-0.4, 0.4, n)
    for i in range(1, 7):
        table[f"qs{i}"] = table[f"q{i}"] + rng.normal(0, 1e-4, n)
    table["temp_ambient"] = rng.uniform(18.0, 25.0, n)
    table["temp_j2"] = rng.uniform(18.0, 40.0, n)
    xyz = rng.normal(0, 1.0, (n, 3))
    quat = rng.normal(size=(n, 4))
    quat /= np.linalg.norm(quat, axis=1, keepdims=True)
    for i, c in enumerate(("x", "y", "z", "qx", "qy", "qz", "qw")):
        table[c] = np.concatenate([xyz, quat], axis=1)[:, i]
    table["true_x"] = xyz[:, 0] + 1e-4
    meta = DatasetMeta(
        robot="ur10",
        frame="tracker",
        T_W_0=transform_from_xyz_rpy([2.0, 1.0, -1.0], [0.1, 0.2, 0.3]).tolist(),
        T_6_S=np.eye(4).tolist(),
        noise_floor_m=1.5e-5,
        extra={"source": "test", "n": n},
    )
    return Dataset(table, meta)


@pytest.mark.parametrize("suffix", [".parquet", ".csv"])
def test_round_trip_is_exact(tmp_path, suffix):
    ds = make()
    path = write_dataset(ds, tmp_path / f"d{suffix}")
    assert meta_path(path).exists()
    back = read_dataset(path)
    pd.testing.assert_frame_equal(back.table, ds.table, check_exact=True)
    assert back.meta == ds.meta


def test_parquet_carries_its_meta_without_the_sidecar(tmp_path):
    path = write_dataset(make(), tmp_path / "d.parquet")
    meta_path(path).unlink()
    assert read_dataset(path).meta == make().meta


def test_accessors():
    ds = make()
    assert ds.n_joints == 6 and ds.q().shape == (25, 6)
    np.testing.assert_allclose(ds.deflection(), ds.table[[f"qs{i}" for i in range(1, 7)]] - ds.q())
    assert ds.temperatures().shape == (25, 2)
    T_W_S = ds.measured_poses()
    np.testing.assert_allclose(
        np.asarray(ds.meta.T_W_0) @ ds.measured_poses_base(), T_W_S, atol=1e-12
    )
    xyz, quat = xyz_quat_from_transform(T_W_S)
    np.testing.assert_allclose(xyz, ds.table[["x", "y", "z"]].to_numpy())
    assert len(ds.subset(np.array([3, 1]))) == 2
    with pytest.raises(DatasetError, match="T_W_0 is unknown"):
        poses_in_base(T_W_S, "tracker", None)


def test_one_rule_for_temperature_channels():
    assert temperature_column("ambient") == temperature_column("temp_ambient") == "temp_ambient"
    assert temperature_name("temp_ambient") == "ambient" == temperature_name("ambient")
    assert temperature_name(temperature_column("temp")) == "temp"
    assert temperature_columns(make().table) == ["temp_ambient", "temp_j2"]
    assert temperature_columns(("q1", "dtheta1", "temp_j2", "temperature")) == ["temp_j2"]


def write_edited(tmp_path, edit) -> str:
    ds = make()
    return write_dataset(Dataset(edit(ds.table.copy()), ds.meta), tmp_path / "d.csv")


def set_cell(row, col, value):
    def edit(table):
        table.loc[row, col] = value
        return table

    return edit


@pytest.mark.parametrize(
    "edit, match",
    [
        (lambda t: t.drop(columns=["qw", "t"]), r"missing column\(s\) t, qw"),
        (lambda t: t.drop(columns=[f"q{i}" for i in range(1, 7)]), r"missing column\(s\) q1"),
        (set_cell(7, "y", np.nan), "row 7, column 'y': value is not a finite number"),
        (set_cell(3, "temp_j2", np.inf), "row 3, column 'temp_j2': value is not a finite"),
        (set_cell(5, "qx", 2.0), "row 5: quaternion norm .*, expected 1"),
        (lambda t: t.drop(columns=["qs6"]), "5 secondary columns qs\\* for 6 joints"),
        (lambda t: t.iloc[:0], ": no rows"),
    ],
)
def test_bad_files_name_row_and_column(tmp_path, edit, match):
    path = write_edited(tmp_path, edit)
    with pytest.raises(DatasetError, match=match) as info:
        read_dataset(path)
    assert "\n" not in str(info.value) and str(path) in str(info.value)


def test_joint_beyond_limits(tmp_path):
    path = write_edited(tmp_path, set_cell(9, "q2", 1.7))
    fanuc = load_description("fanuc_m900ib700")
    with pytest.raises(DatasetError, match=r"row 9, column 'q2': 97.403 deg outside .*-64.0, 90.0"):
        read_dataset(path, limits_rad=fanuc.limits_rad)
    read_dataset(path, limits_rad=load_description("ur10").limits_rad)


def test_bad_meta_and_suffix(tmp_path):
    with pytest.raises(DatasetError, match="meta.frame must be one of"):
        DatasetMeta(robot="ur10", frame="world")
    with pytest.raises(DatasetError, match="meta.T_W_0 must be a 4x4"):
        DatasetMeta(robot="ur10", T_W_0=[[1.0, 0.0]])
    with pytest.raises(DatasetError, match="end in .parquet or .csv, got '.xlsx'"):
        write_dataset(make(), tmp_path / "d.xlsx")
    path = write_dataset(make(), tmp_path / "d.csv")
    meta_path(path).write_text(json.dumps({"robot": "ur10", "colour": "red"}))
    with pytest.raises(DatasetError, match="bad metadata"):
        read_dataset(path)
    meta_path(path).unlink()
    with pytest.raises(DatasetError, match=r"no metadata \(expected d.meta.json\)"):
        read_dataset(path)
    base = Dataset(make().table, DatasetMeta(robot="ur10", frame="tracker"))
    with pytest.raises(DatasetError, match="meta.T_W_0 is unknown"):
        base.measured_poses_base()


class Unprintable:
    """A cell value whose text conversion fails half-way through a CSV write."""

    def __str__(self) -> str:
        raise RuntimeError("disk full")

    __repr__ = __str__


def test_failed_write_leaves_old_file_intact(tmp_path):
    path = write_dataset(make(seed=1), tmp_path / "d.csv")
    before = path.read_bytes()
    # 10,000 rows: pandas writes two chunks to the temporary file before the bad last cell.
    table = make(n=10_000, seed=2).table.astype({"true_x": object})
    table.loc[9_999, "true_x"] = Unprintable()
    with pytest.raises(RuntimeError, match="disk full"):
        write_dataset(Dataset(table, make().meta), path)
    assert path.read_bytes() == before
    assert sorted(p.name for p in tmp_path.iterdir()) == sorted([path.name, meta_path(path).name])
    validate(read_dataset(path), str(path))
