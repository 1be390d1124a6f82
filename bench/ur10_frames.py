"""Frames and uncalibrated accuracy of the real UR10 series (``../shared/data/ur10-ipa``).

For each series: (1) the recorded commanded ("Goal") poses against the nominal FK of the
recorded joint angles, with and without UR's base convention (``T_UR_0 = Rz(pi)``), and the
base/tool transform a free ``AX = ZB`` fit finds between them; (2) which Euler convention of
the tracker angles makes the frame fit residual small; (3) the direction of
``Trafo_TM_F_init.txt``; (4) the uncalibrated accuracy after frames identification, on all
points and on a held-out half (frames fitted on the other half).

    .venv/bin/python bench/ur10_frames.py
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation

from kinematics.accuracy import accuracy_summary
from kinematics.dataset import Dataset, DatasetMeta
from kinematics.description import load_description
from kinematics.frames import fit_frames
from kinematics.importers.ipa import (
    GOAL,
    JOINTS,
    MEAS_POS,
    MEAS_ROT,
    T_UR_0,
    import_series,
    read_semicolon_csv,
    read_trafo,
)
from kinematics.measurability import measurability_from_poses
from kinematics.model import RobotModel
from kinematics.transforms import ARCMIN_PER_RAD, invert, transform

DATA = Path(__file__).resolve().parents[2] / "shared" / "data" / "ur10-ipa"


def deviation(T_a: np.ndarray, T_b: np.ndarray) -> str:
    """Mean/max position (mm) and angle (arcmin) between pose sets."""
    mm = 1e3 * np.linalg.norm(T_a[:, :3, 3] - T_b[:, :3, 3], axis=1)
    am = (
        ARCMIN_PER_RAD
        * Rotation.from_matrix(T_a[:, :3, :3] @ np.swapaxes(T_b[:, :3, :3], 1, 2)).magnitude()
    )
    return (
        f"mean {mm.mean():.3f} mm, max {mm.max():.3f} mm; "
        f"mean {am.mean():.2f} arcmin, max {am.max():.2f} arcmin"
    )


def frame_gap(T_a: np.ndarray, T_b: np.ndarray) -> str:
    mm = 1e3 * np.linalg.norm(T_a[:3, 3] - T_b[:3, 3])
    deg = np.rad2deg(Rotation.from_matrix(T_a[:3, :3] @ T_b[:3, :3].T).magnitude())
    return f"{mm:.2f} mm, {deg:.3f} deg"


def goal_report(raw, flange: np.ndarray, tcp: np.ndarray) -> None:
    goal = transform(
        Rotation.from_euler("xyz", raw[list(GOAL[3:])].to_numpy(float)).as_matrix(),
        raw[list(GOAL[:3])].to_numpy(float),
    )
    print("  Goal (fixed-axis RPY) vs nominal FK of the recorded joints, TCP = inv(Trafo file):")
    print(f"    in the DH base as is:          {deviation(goal, flange @ tcp[None])}")
    print(
        f"    with T_UR_0 = Rz(180 deg):     {deviation(goal, T_UR_0[None] @ flange @ tcp[None])}"
    )
    free = fit_frames(goal, flange)
    yaw = np.rad2deg(Rotation.from_matrix(free.T_W_0[:3, :3]).as_rotvec())
    print(
        f"    free AX=ZB fit: base rotvec {np.round(yaw, 3)} deg, "
        f"{frame_gap(free.T_W_0, T_UR_0)} from Rz(180); tool {frame_gap(free.T_6_S, tcp)} "
        f"from inv(Trafo); residual mean {free.summary().mean_mm:.3f} mm, "
        f"{free.summary().mean_arcmin:.2f} arcmin"
    )


def euler_report(raw, flange: np.ndarray) -> None:
    pos = raw[list(MEAS_POS)].to_numpy(float) / 1e3
    angles = raw[list(MEAS_ROT)].to_numpy(float)
    for conv in ("XYZ", "xyz", "ZYX", "zyx"):
        T = transform(Rotation.from_euler(conv, angles, degrees=True).as_matrix(), pos)
        s = fit_frames(T, flange).summary()
        print(
            f"  tracker angles as from_euler({conv!r}): frame fit mean {s.mean_mm:.3f} mm, "
            f"max {s.max_mm:.3f} mm, mean {s.mean_arcmin:.2f} arcmin"
        )


def held_out(ds: Dataset, flange: np.ndarray, desc, seed: int = 0) -> str:
    """Accuracy on a random half with frames fitted on the other half."""
    idx = np.random.default_rng(seed).permutation(len(ds))
    train, test = idx[: len(ds) // 2], idx[len(ds) // 2 :]
    fit = fit_frames(ds.measured_poses()[train], flange[train])
    meta = DatasetMeta(
        robot="ur10", frame="tracker", T_W_0=fit.T_W_0.tolist(), T_6_S=fit.T_6_S.tolist()
    )
    s = accuracy_summary(Dataset(ds.table.iloc[test].reset_index(drop=True), meta), desc)
    return (
        f"mean {s.mean_mm:.3f} mm, std {s.std_mm:.3f}, p95 {s.p95_mm:.3f}, max {s.max_mm:.3f} mm;"
        f" mean {s.mean_arcmin:.2f} arcmin, max {s.max_arcmin:.2f} arcmin (N = {s.n})"
    )


def series_report(folder: Path) -> None:
    desc = load_description("ur10")
    path = next(folder.glob("measurements_*.csv"))
    raw = read_semicolon_csv(path, (*GOAL, *JOINTS, *MEAS_POS, *MEAS_ROT))
    flange = RobotModel(desc).fk(raw[list(JOINTS)].to_numpy(float), frame="flange")
    trafo = read_trafo(folder / "Trafo_TM_F_init.txt")
    print(f"\n== {folder.name}: {len(raw)} points ({path.name})")
    goal_report(raw, flange, invert(trafo))
    euler_report(raw, flange)
    t0 = time.perf_counter()
    result = import_series(folder)
    elapsed = time.perf_counter() - t0
    ds, fit = result.dataset, result.fit
    print(f"  import + frames identification: {elapsed:.1f} s, {fit.nfev} evaluations")
    T_6_S = fit.T_6_S
    print(
        f"  T_6_S vs Trafo file as is: {frame_gap(trafo, T_6_S)}; inverted: "
        f"{frame_gap(invert(trafo), T_6_S)}"
    )
    print(
        f"  T_6_S identified: p = {np.round(1e3 * T_6_S[:3, 3], 2)} mm, "
        f"rotvec = {np.round(np.rad2deg(Rotation.from_matrix(T_6_S[:3, :3]).as_rotvec()), 2)} deg"
    )
    if "handeye_T_W_0_vs_T_W_0" in ds.meta.extra:
        gap = ds.meta.extra["handeye_T_W_0_vs_T_W_0"]
        print(
            f"  T_W_0 from calibration_handeye.csv vs all rows: {gap['mm']:.2f} mm, "
            f"{gap['arcmin']:.2f} arcmin (hand-eye fit mean "
            f"{ds.meta.extra['handeye_fit_mean_mm']:.3f} mm)"
        )
    vis = measurability_from_poses(ds.measured_poses())
    print(
        f"  recorded poses measurable: {vis.visible.mean():.1%}; incidence max "
        f"{np.rad2deg(vis.angle_rad.max()):.1f} deg; distance {vis.distance_m.min():.2f}–"
        f"{vis.distance_m.max():.2f} m"
    )
    s = accuracy_summary(ds, desc)
    print(
        f"  uncalibrated accuracy, frames from all points: mean {s.mean_mm:.3f} mm, "
        f"std {s.std_mm:.3f}, p95 {s.p95_mm:.3f}, max {s.max_mm:.3f} mm; "
        f"mean {s.mean_arcmin:.2f} arcmin, max {s.max_arcmin:.2f} arcmin (N = {s.n})"
    )
    print(f"  uncalibrated accuracy, held-out half:     {held_out(ds, flange, desc)}")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--data", type=Path, default=DATA, help="the ur10-ipa folder")
    args = parser.parse_args()
    for series in ("Series_A", "Series_B"):
        series_report(args.data / series)


if __name__ == "__main__":
    main()
