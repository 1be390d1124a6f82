"""Importer for the UR10 laser-tracker series of Landgraf et al. (``../shared/data/ur10-ipa``).

A series folder holds ``measurements_*.csv`` (semicolon, decimal comma): the commanded pose
``Goal x..yaw`` (m, rad; UR base frame, fixed-axis roll-pitch-yaw), six joint angles (rad),
``measurement_temperature`` (°C), the T-Mac pose ``measurement_x, _y, _z`` (mm) and
``_rx, _ry, _rz`` (degrees, intrinsic X-Y-Z Euler: ``Rotation.from_euler("XYZ", ...)``; the
extrinsic and Z-Y-X readings leave 27–60 mm frame-fit residuals against 0.76 mm), optional
``measurement_std_*`` columns; ``Trafo_TM_F_init.txt`` (mm) and, in series B,
``calibration_handeye.csv``.

Findings the importer relies on (bench/ur10_frames.py measures them):

- UR's base frame is the DH base rotated 180° about z: ``T_UR_0 = Rz(pi)``.
- ``Trafo_TM_F_init.txt`` is ``T_TM_F``, the flange seen from the TCP: its inverse matches the
  controller's TCP (109 mm along the flange z) to 0.02 mm. The probe frame the tracker reports
  is that TCP turned 180° about z and about 16 mm nearer the flange, so the file is only a start.
- ``calibration_handeye.csv`` gives flange poses in UR's base and in ROS's ``flange`` axes; its
  own ``AX = ZB`` fit yields ``T_W_UR``, hence the start ``T_W_0 = T_W_UR · Rz(pi)``.
- Series B's ``Timestamp`` was mangled by a spreadsheet (``2,02011E+13``): row order is then the
  only time, ``t`` is the row index and ``meta.extra["time_source"]`` says ``"row_order"``.
"""

from __future__ import annotations

import re
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pandas as pd
from scipy.spatial.transform import Rotation

from kinematics.dataset import (
    Dataset,
    DatasetMeta,
    temperature_column,
    validate,
    write_dataset,
)
from kinematics.description import load_description
from kinematics.errors import DatasetError
from kinematics.frames import FrameFit, fit_frames, fit_frames_screened
from kinematics.model import RobotModel, rot_z
from kinematics.transforms import (
    ARCMIN_PER_RAD,
    invert,
    rotation_angle,
    transform,
    xyz_quat_from_transform,
)

JOINTS = (
    "shoulder_pan_joint",
    "shoulder_lift_joint",
    "elbow_joint",
    "wrist_1_joint",
    "wrist_2_joint",
    "wrist_3_joint",
)
GOAL = ("Goal x", "Goal y", "Goal z", "Goal roll", "Goal pitch", "Goal yaw")
MEAS_POS = ("measurement_x", "measurement_y", "measurement_z")
MEAS_ROT = ("measurement_rx", "measurement_ry", "measurement_rz")
REQUIRED = ("Timestamp", *GOAL, *JOINTS, "measurement_temperature", *MEAS_POS, *MEAS_ROT)
HANDEYE = ("flange_x", "flange_y", "flange_z", "flange_qx", "flange_qy", "flange_qz", "flange_qw")
EULER = "XYZ"
T_UR_0 = rot_z(np.pi)
_TIMESTAMP = re.compile(r"^\d{14}$")
_MANGLED = re.compile(r"^\d,\d+E\+\d+$", re.IGNORECASE)


@dataclass(frozen=True, kw_only=True)
class IpaImport:
    """An imported series: the dataset, the frame fit that set its meta, and where it went."""

    dataset: Dataset
    fit: FrameFit
    series: str
    path: Path | None


def read_semicolon_csv(path: Path, required: tuple[str, ...]) -> pd.DataFrame:
    """A semicolon/decimal-comma CSV with ``required`` columns, all but Timestamp numeric."""
    if not path.is_file():
        raise DatasetError(f"{path}: no such file")
    try:
        raw = pd.read_csv(path, sep=";", decimal=",", dtype={"Timestamp": str})
    except (pd.errors.ParserError, pd.errors.EmptyDataError, UnicodeDecodeError) as exc:
        raise DatasetError(f"{path}: unreadable: {str(exc).splitlines()[0]}") from None
    missing = [c for c in required if c not in raw.columns]
    if missing:
        raise DatasetError(f"{path}: missing column(s) {', '.join(missing)}")
    for col in raw.columns:
        if col == "Timestamp":
            continue
        column = raw[col]
        if not pd.api.types.is_numeric_dtype(column):  # a bad cell stops decimal-comma parsing
            column = column.astype(str).str.replace(",", ".", regex=False)
        values = pd.to_numeric(column, errors="coerce").to_numpy(float)
        bad = np.flatnonzero(~np.isfinite(values))
        if bad.size:
            raise DatasetError(
                f"{path}: line {bad[0] + 2}, column {col!r}: expected a finite number, "
                f"got {raw[col].iloc[bad[0]]!r}"
            )
        raw[col] = values
    if raw.empty:
        raise DatasetError(f"{path}: no rows")
    return raw


def read_trafo(path: Path) -> np.ndarray:
    """A 4x4 transform from a whitespace text file in mm, returned in m."""
    try:
        T = np.loadtxt(path)
    except (OSError, ValueError) as exc:
        raise DatasetError(f"{path}: unreadable transform: {exc}") from None
    if T.shape != (4, 4) or not np.allclose(T[3], [0, 0, 0, 1]):
        raise DatasetError(f"{path}: expected a 4x4 homogeneous transform, got shape {T.shape}")
    T[:3, 3] /= 1e3
    return T


def times(stamps: pd.Series, path: Path) -> tuple[np.ndarray, str]:
    """``t`` (s from the first row) and its source: ``"timestamp"`` or ``"row_order"``."""
    text = stamps.astype(str).str.strip()
    if text.map(lambda s: bool(_TIMESTAMP.match(s))).all():
        ts = pd.to_datetime(text, format="%Y%m%d%H%M%S")
        return (ts - ts.iloc[0]).dt.total_seconds().to_numpy(float), "timestamp"
    if text.map(lambda s: bool(_MANGLED.match(s))).all():
        return np.arange(len(text), dtype=float), "row_order"
    bad = int(np.flatnonzero(~text.map(lambda s: bool(_TIMESTAMP.match(s))).to_numpy())[0])
    raise DatasetError(
        f"{path}: line {bad + 2}, column 'Timestamp': expected YYYYMMDDhhmmss, got {text[bad]!r}"
    )


def tracker_poses(raw: pd.DataFrame) -> np.ndarray:
    """Measured T-Mac poses ``T_W_S`` ``(N, 4, 4)`` in m from mm and X-Y-Z Euler degrees."""
    R = Rotation.from_euler(EULER, raw[list(MEAS_ROT)].to_numpy(float), degrees=True)
    return transform(R.as_matrix(), raw[list(MEAS_POS)].to_numpy(float) / 1e3)


def handeye_base_start(path: Path) -> tuple[np.ndarray, FrameFit]:
    """``T_W_0`` from ``calibration_handeye.csv`` (flange poses in UR's base) and its fit."""
    raw = read_semicolon_csv(path, (*HANDEYE, *MEAS_POS, *MEAS_ROT))
    quat = raw[list(HANDEYE[3:])].to_numpy(float)
    flange = transform(Rotation.from_quat(quat).as_matrix(), raw[list(HANDEYE[:3])].to_numpy())
    fit = fit_frames(tracker_poses(raw), flange)
    return fit.T_W_0 @ T_UR_0, fit


def dataset_table(
    raw: pd.DataFrame, t: np.ndarray, T_W_S: np.ndarray
) -> tuple[pd.DataFrame, tuple[float, float] | None]:
    """The dataset columns (SI) and, with std columns, the median noise (m, rad).

    Extra columns: ``goal_x, goal_y, goal_z`` (m), ``goal_roll, goal_pitch, goal_yaw`` (rad)
    and, where present, ``std_x, std_y, std_z`` (m), ``std_rx, std_ry, std_rz`` (rad). The
    noise level is the median over rows of the norm of the three per-axis stds.
    """
    xyz, quat = xyz_quat_from_transform(T_W_S)
    columns = {"t": t}
    columns |= {f"q{i}": raw[name].to_numpy(float) for i, name in enumerate(JOINTS, start=1)}
    columns[temperature_column("ambient")] = raw["measurement_temperature"].to_numpy(float)
    columns |= dict(zip(("x", "y", "z"), xyz.T, strict=True))
    columns |= dict(zip(("qx", "qy", "qz", "qw"), quat.T, strict=True))
    for col, name in zip(GOAL, ("x", "y", "z", "roll", "pitch", "yaw"), strict=True):
        columns[f"goal_{name}"] = raw[col].to_numpy(float)
    std_cols = [f"measurement_std_{a}" for a in ("x", "y", "z", "rx", "ry", "rz")]
    if not all(c in raw.columns for c in std_cols):
        return pd.DataFrame(columns), None
    std = raw[std_cols].to_numpy(float)
    std[:, :3] /= 1e3
    std[:, 3:] = np.deg2rad(std[:, 3:])
    columns |= {c.replace("measurement_", ""): v for c, v in zip(std_cols, std.T, strict=True)}
    noise = (
        float(np.median(np.linalg.norm(std[:, :3], axis=1))),
        float(np.median(np.linalg.norm(std[:, 3:], axis=1))),
    )
    return pd.DataFrame(columns), noise


def _frame_gap(T_a: np.ndarray, T_b: np.ndarray) -> dict[str, float]:
    """Position (mm) and angle (arcmin) between two frames, for the metadata."""
    return {
        "mm": float(1e3 * np.linalg.norm(T_a[:3, 3] - T_b[:3, 3])),
        "arcmin": float(ARCMIN_PER_RAD * rotation_angle(T_a[:3, :3] @ T_b[:3, :3].T)),
    }


def _check_limits(q: np.ndarray, limits_rad: np.ndarray, path: Path) -> None:
    out = np.argwhere((q < limits_rad[:, 0]) | (q > limits_rad[:, 1]))
    if out.size:
        r, c = out[0]
        lo, hi = np.rad2deg(limits_rad[c])
        raise DatasetError(
            f"{path}: line {r + 2}, column {JOINTS[c]!r}: {np.rad2deg(q[r, c]):.3f} deg outside "
            f"the joint limits [{lo:.1f}, {hi:.1f}] deg"
        )


def _measurement_file(folder: Path) -> Path:
    if not folder.is_dir():
        raise DatasetError(f"{folder}: no such series folder")
    files = sorted(folder.glob("measurements_*.csv"))
    if len(files) != 1:
        raise DatasetError(f"{folder}: expected one measurements_*.csv, found {len(files)}")
    return files[0]


def import_series(
    folder: str | Path,
    *,
    robot: str = "ur10",
    out: str | Path | None = None,
    progress: Callable[[str], None] | None = None,
    frames_rows: int | None = None,
) -> IpaImport:
    """Import one series folder into the dataset format (tracker frame), identifying frames.

    ``T_W_0`` and ``T_6_S`` come from :func:`kinematics.frames.fit_frames_screened` on all rows
    (the first ``frames_rows`` only, if given: what a new day knows of its frames from its first
    points, before a model carried into it has seen the rest; a gross outlier among them is left
    out of the fit and named in ``extra["frame_fit_left_out_rows"]``, kept in the table), started
    from the inverted ``Trafo_TM_F_init.txt`` and, where present, the hand-eye file. Writes
    ``out`` (``.parquet`` or ``.csv`` plus sidecar) when given. ``progress`` is called with the
    name of each finished stage (read, frames, table, write).
    """
    progress = progress or (lambda stage: None)
    folder = Path(folder)
    suffix = None if out is None else Path(out).suffix
    if suffix not in (None, ".parquet", ".csv"):
        raise DatasetError(f"{out}: dataset files end in .parquet or .csv, got {suffix!r}")
    path = _measurement_file(folder)
    raw = read_semicolon_csv(path, REQUIRED)
    desc = load_description(robot)
    t, time_source = times(raw["Timestamp"], path)
    q = raw[list(JOINTS)].to_numpy(float)
    _check_limits(q, desc.limits_rad, path)
    T_W_S = tracker_poses(raw)
    extra: dict = {
        "source": f"ur10-ipa/{folder.name}/{path.name}",
        "time_source": time_source,
        "euler_convention": f"intrinsic {EULER} (scipy from_euler('{EULER}'), degrees)",
        "goal_frame": "UR base = DH base rotated 180 deg about z; fixed-axis RPY",
    }
    if time_source == "row_order":
        extra["t_unit"] = "row index (Timestamp column was spreadsheet-mangled)"
    else:
        extra["n_time_reversals"] = int(np.sum(np.diff(t) < 0))
    S6_init = invert(read_trafo(folder / "Trafo_TM_F_init.txt"))
    W0_init = None
    if (folder / "calibration_handeye.csv").is_file():
        W0_init, he_fit = handeye_base_start(folder / "calibration_handeye.csv")
        extra["handeye_fit_mean_mm"] = he_fit.summary().mean_mm
    flange = RobotModel(desc).fk(q, frame="flange")
    progress("read")
    n = len(q) if frames_rows is None else frames_rows
    if frames_rows is not None:
        if not 3 <= n <= len(q):
            raise DatasetError(f"{path}: frames_rows must be in [3, {len(q)}] rows, got {n}")
        extra["frames_rows"] = n
    fit, left_out = fit_frames_screened(
        T_W_S[:n], flange[:n], T_W_0_init=W0_init, T_6_S_init=S6_init
    )
    progress("frames")
    extra["frame_fit"] = fit.summary().to_dict()
    extra["frame_fit_left_out_rows"] = left_out.tolist()
    extra["trafo_inverse_vs_T_6_S"] = _frame_gap(S6_init, fit.T_6_S)
    if W0_init is not None:
        extra["handeye_T_W_0_vs_T_W_0"] = _frame_gap(W0_init, fit.T_W_0)

    table, noise = dataset_table(raw, t, T_W_S)
    if noise is not None:
        extra["noise_orientation_rad"] = noise[1]
    meta = DatasetMeta(
        robot=desc.name,
        frame="tracker",
        T_W_0=fit.T_W_0.tolist(),
        T_6_S=fit.T_6_S.tolist(),
        noise_floor_m=None if noise is None else noise[0],
        extra=extra,
    )
    ds = Dataset(table, meta)
    validate(ds, str(path))
    progress("table")
    written = write_dataset(ds, out) if out is not None else None
    progress("write")
    return IpaImport(dataset=ds, fit=fit, series=folder.name, path=written)
