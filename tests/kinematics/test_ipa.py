"""The UR10 (ur10-ipa) importer: synthetic series in the same layout, and the real data."""

from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from scipy.spatial.transform import Rotation

from kinematics.dataset import read_dataset
from kinematics.description import load_description
from kinematics.errors import DatasetError
from kinematics.importers.ipa import JOINTS, T_UR_0, import_series
from kinematics.measurability import measurability_from_poses
from kinematics.model import RobotModel
from kinematics.transforms import transform_from_xyz_rpy

T_W_0 = transform_from_xyz_rpy([0.5, -3.5, -1.2], [0.003, -0.001, 0.35])
T_6_S = transform_from_xyz_rpy([0.0, 0.0005, 0.093], [0.002, 0.0, -np.pi / 2])
TRAFO_MM = "0 1 0 0\n-1 0 0 0.087\n0 0 1 -109\n0 0 0 1\n"


def write_series(folder: Path, n: int = 60, timestamps: str = "ok", seed: int = 0) -> np.ndarray:
    """A synthetic series in the ur10-ipa layout (exact poses); returns the joint angles."""
    folder.mkdir(parents=True, exist_ok=True)
    model = RobotModel(load_description("ur10"))
    q = np.random.default_rng(seed).uniform(-2.5, 2.5, (n, 6))
    flange = model.fk(q, frame="flange")
    T = T_W_0[None] @ flange @ T_6_S[None]
    goal = T_UR_0[None] @ flange
    cols = {
        "Timestamp": (
            [f"202007141639{k % 60:02d}" for k in range(n)]
            if timestamps == "ok"
            else ["2,02011E+13"] * n
        ),
        "Goal x": goal[:, 0, 3],
        "Goal y": goal[:, 1, 3],
        "Goal z": goal[:, 2, 3],
    }
    rpy = Rotation.from_matrix(goal[:, :3, :3]).as_euler("xyz")
    cols.update({"Goal roll": rpy[:, 0], "Goal pitch": rpy[:, 1], "Goal yaw": rpy[:, 2]})
    for i, name in enumerate(JOINTS):
        cols[name] = q[:, i]
    cols["measurement_temperature"] = np.full(n, 22.5)
    for i, a in enumerate("xyz"):
        cols[f"measurement_{a}"] = 1e3 * T[:, i, 3]
    euler = Rotation.from_matrix(T[:, :3, :3]).as_euler("XYZ", degrees=True)
    for i, a in enumerate(("rx", "ry", "rz")):
        cols[f"measurement_{a}"] = euler[:, i]
        cols[f"measurement_std_{a[-1]}"] = np.full(n, 0.02)
        cols[f"measurement_std_{a}"] = np.full(n, 0.002)
    frame = pd.DataFrame(cols)
    frame.to_csv(folder / "measurements_synthetic.csv", sep=";", decimal=",", index=False)
    (folder / "Trafo_TM_F_init.txt").write_text(TRAFO_MM)
    return q


def gap(T_a, T_b) -> float:
    return max(
        float(np.linalg.norm(T_a[:3, 3] - T_b[:3, 3])),
        float(Rotation.from_matrix(T_a[:3, :3] @ T_b[:3, :3].T).magnitude()),
    )


def test_synthetic_series_round_trip(tmp_path):
    q = write_series(tmp_path / "S")
    stages = []
    result = import_series(tmp_path / "S", out=tmp_path / "s.parquet", progress=stages.append)
    assert stages == ["read", "frames", "table", "write"]
    ds = read_dataset(result.path)
    assert len(ds) == 60 and ds.meta.robot == "ur10" and ds.meta.frame == "tracker"
    np.testing.assert_allclose(ds.q(), q, atol=0)
    assert gap(np.asarray(ds.meta.T_W_0), T_W_0) < 1e-7
    assert gap(np.asarray(ds.meta.T_6_S), T_6_S) < 1e-7
    assert ds.meta.extra["time_source"] == "timestamp"
    np.testing.assert_allclose(ds.table["t"].to_numpy()[:3], [0.0, 1.0, 2.0])
    assert ds.meta.noise_floor_m == pytest.approx(np.sqrt(3) * 0.02e-3)
    assert ds.table["std_rx"].iloc[0] == pytest.approx(np.deg2rad(0.002))
    assert {"goal_x", "goal_yaw", "temp_ambient"} <= set(ds.table.columns)
    # The inverted transform file is 180 deg away from the probe frame the tracker reports.
    assert ds.meta.extra["trafo_inverse_vs_T_6_S"]["arcmin"] == pytest.approx(10800, abs=10)


def test_mangled_timestamps_become_row_order(tmp_path):
    write_series(tmp_path / "S", n=20, timestamps="mangled")
    ds = import_series(tmp_path / "S").dataset
    assert ds.meta.extra["time_source"] == "row_order"
    assert "row index" in ds.meta.extra["t_unit"]
    np.testing.assert_array_equal(ds.table["t"].to_numpy(), np.arange(20.0))


def corrupt(path: Path, column: str, row: int, value: str) -> None:
    frame = pd.read_csv(path, sep=";", dtype=str)
    frame.loc[row, column] = value
    frame.to_csv(path, sep=";", index=False)


@pytest.mark.parametrize(
    "column, value, match",
    [
        ("measurement_x", "abc", r"line 5, column 'measurement_x': expected a finite number"),
        ("elbow_joint", "", r"line 5, column 'elbow_joint'"),
        ("Timestamp", "yesterday", r"line 5, column 'Timestamp': expected YYYYMMDDhhmmss"),
        ("wrist_3_joint", "7,5", r"line 5, column 'wrist_3_joint': 429.718 deg outside"),
    ],
)
def test_bad_cells_name_line_and_column(tmp_path, column, value, match):
    write_series(tmp_path / "S", n=10)
    corrupt(tmp_path / "S" / "measurements_synthetic.csv", column, 3, value)
    with pytest.raises(DatasetError, match=match):
        import_series(tmp_path / "S")


def test_missing_column_and_files(tmp_path):
    write_series(tmp_path / "S", n=10)
    csv = tmp_path / "S" / "measurements_synthetic.csv"
    pd.read_csv(csv, sep=";", dtype=str).drop(columns=["Goal z"]).to_csv(csv, sep=";", index=False)
    with pytest.raises(DatasetError, match=r"missing column\(s\) Goal z"):
        import_series(tmp_path / "S")
    with pytest.raises(DatasetError, match="end in .parquet or .csv, got '.txt'"):
        import_series(tmp_path / "S", out=tmp_path / "out.txt")
    with pytest.raises(DatasetError, match="no such series folder"):
        import_series(tmp_path / "nowhere")
    (tmp_path / "E").mkdir()
    with pytest.raises(DatasetError, match=r"expected one measurements_\*.csv, found 0"):
        import_series(tmp_path / "E")
    write_series(tmp_path / "T", n=10)
    (tmp_path / "T" / "Trafo_TM_F_init.txt").write_text("1 2 3\n")
    with pytest.raises(DatasetError, match="Trafo_TM_F_init.txt: expected a 4x4"):
        import_series(tmp_path / "T")


def test_frames_from_the_first_rows_only(tmp_path):
    """A tracker bumped 2 mm along x after the 30th row: frames from the first 30 rows are the
    first set-up's, frames from every row are neither set-up's."""
    write_series(tmp_path / "S", n=60)
    csv = tmp_path / "S" / "measurements_synthetic.csv"
    frame = pd.read_csv(csv, sep=";", decimal=",")
    frame.loc[30:, "measurement_x"] += 2.0
    frame.to_csv(csv, sep=";", decimal=",", index=False)
    first = import_series(tmp_path / "S", frames_rows=30).dataset
    assert gap(np.asarray(first.meta.T_W_0), T_W_0) < 1e-7
    assert gap(np.asarray(first.meta.T_6_S), T_6_S) < 1e-7
    assert first.meta.extra["frames_rows"] == 30 and len(first) == 60
    every = import_series(tmp_path / "S").dataset
    assert gap(np.asarray(every.meta.T_W_0), T_W_0) > 5e-4
    assert "frames_rows" not in every.meta.extra
    with pytest.raises(DatasetError, match=r"frames_rows must be in \[3, 60\] rows, got 2"):
        import_series(tmp_path / "S", frames_rows=2)


def test_a_lost_beam_is_left_out_of_the_frame_fit_and_kept_in_the_table(tmp_path):
    """Exact synthetic poses (every row alike to the tracker's noise) with one row 1 m off:
    the frames are fitted without it, as exactly as without the row, and the row is kept."""
    write_series(tmp_path / "S", n=60)
    csv = tmp_path / "S" / "measurements_synthetic.csv"
    frame = pd.read_csv(csv, sep=";", decimal=",", dtype={"Timestamp": str})
    frame.loc[17, "measurement_x"] += 1000.0
    frame.to_csv(csv, sep=";", decimal=",", index=False)
    ds = import_series(tmp_path / "S").dataset
    assert ds.meta.extra["frame_fit_left_out_rows"] == [17] and len(ds) == 60
    assert gap(np.asarray(ds.meta.T_W_0), T_W_0) < 1e-7
    assert gap(np.asarray(ds.meta.T_6_S), T_6_S) < 1e-7
    write_series(tmp_path / "C", n=60)
    assert import_series(tmp_path / "C").dataset.meta.extra["frame_fit_left_out_rows"] == []


@pytest.mark.shared_data
def test_real_series_b(shared_data, tmp_path):
    result = import_series(shared_data / "ur10-ipa" / "Series_B", out=tmp_path / "b.csv")
    ds = read_dataset(result.path)
    assert len(ds) == 1495
    assert ds.meta.extra["time_source"] == "row_order"
    s = result.fit.summary()
    # Intrinsic X-Y-Z Euler angles make the frame fit close to the UR10's accuracy (~1 mm).
    assert s.mean_mm < 1.5 and s.max_mm < 3.0 and s.mean_arcmin < 10
    # The hand-eye file's base frame agrees with the one identified from all rows.
    assert ds.meta.extra["handeye_T_W_0_vs_T_W_0"]["mm"] < 2.0
    assert ds.meta.extra["frame_fit_left_out_rows"] == []
    assert 5e-6 < ds.meta.noise_floor_m < 1e-4
    # Every recorded pose was measurable, as the tracker saw it.
    vis = measurability_from_poses(ds.measured_poses())
    assert vis.visible.all()


@pytest.mark.shared_data
def test_real_series_a_timestamps(shared_data):
    ds = import_series(shared_data / "ur10-ipa" / "Series_A").dataset
    assert len(ds) == 11911
    assert ds.meta.extra["time_source"] == "timestamp"
    assert ds.table["t"].iloc[1] == 20.0
    assert ds.meta.extra["n_time_reversals"] == 9
    assert ds.meta.extra["frame_fit"]["mean_mm"] < 1.0
