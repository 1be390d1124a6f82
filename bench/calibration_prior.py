"""What a calibration of one region's points does elsewhere, with the calibration prior
(``CalibrationConfig.prior_mm``) and without it: the geometric calibration and ``robocal gap``'s
model of slices of UR10 Series A in recorded order (a stream's first points lie in one region
of the workspace) and of spread points (every 10th point), each fitted both ways, with the mean
position error (mm) on the slice and on the rest of the series (same tracker frame), beside
the nominal model's.

    .venv/bin/python bench/calibration_prior.py
"""

from __future__ import annotations

import time
from pathlib import Path

import numpy as np

from kinematics.calibration import CalibrationConfig, calibrate
from kinematics.dataset import Dataset
from kinematics.description import load_description
from kinematics.effects import perturbed_poses
from kinematics.gap.workflow import GapConfig, run_gap
from kinematics.identification.conditions import cell_description, observations_from_dataset
from kinematics.importers.ipa import import_series
from kinematics.model import RobotModel

UR10_A = Path(__file__).resolve().parents[2] / "shared" / "data" / "ur10-ipa" / "Series_A"
SLICES = {"first 50": slice(0, 50), "first 200": slice(0, 200), "first 600": slice(0, 600)}
SLICES |= {"3000-3600": slice(3000, 3600), "every 10th": slice(0, None, 10)}


def _slice_and_rest(T: np.ndarray, P: np.ndarray, inside: np.ndarray) -> str:
    """Mean position error (mm) of poses ``P`` against ``T`` on the slice / on the rest."""
    err = np.linalg.norm(T[:, :3, 3] - P[:, :3, 3], axis=1) * 1e3
    return f"{err[inside].mean():.3f} / {err[~inside].mean():.3f}"


def predicted(kind: str, ds: Dataset, fit: Dataset, prior_mm: float | None) -> np.ndarray:
    """Poses of all of ``ds`` (tracker frame) from ``kind``'s model of the points ``fit``."""
    desc = cell_description(load_description(ds.meta.robot), ds)
    config = CalibrationConfig(prior_mm=prior_mm)
    q = ds.q()
    if kind == "geometric":
        result = calibrate(desc, fit, config)
        return result.T_W_0[None] @ RobotModel(result.description).fk(q)
    model = run_gap(desc, fit, GapConfig(calibration=config)).model_file()
    cond = observations_from_dataset(ds, model.description).cond
    return model.T_W_0[None] @ perturbed_poses(RobotModel(model.description), cond, model.blocks())


def main() -> None:
    ds = import_series(UR10_A).dataset
    T = ds.measured_poses()
    desc = cell_description(load_description(ds.meta.robot), ds)
    nominal = np.asarray(ds.meta.T_W_0)[None] @ RobotModel(desc).fk(ds.q())
    print(
        "| points fitted | model | nominal: slice / rest | no prior: slice / rest | "
        "prior: slice / rest | s |"
    )
    print("|---|---|---|---|---|---|")
    for name, part in SLICES.items():
        inside = np.zeros(len(ds), dtype=bool)
        inside[part] = True
        fit = ds.subset(np.flatnonzero(inside))
        for kind in ("geometric", "gap"):
            t0 = time.perf_counter()
            cells = [
                _slice_and_rest(T, predicted(kind, ds, fit, prior_mm), inside)
                for prior_mm in (None, CalibrationConfig().prior_mm)
            ]
            seconds = time.perf_counter() - t0
            row = [f"{name} ({inside.sum()})", kind, _slice_and_rest(T, nominal, inside), *cells]
            print(f"| {' | '.join(row)} | {seconds:.0f} |", flush=True)


if __name__ == "__main__":
    main()
