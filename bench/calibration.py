"""Classical geometric calibration next to the uncalibrated error, and the gap workflow, on
the simulated reference campaign and on the real UR10 series (read in place).

    .venv/bin/python bench/calibration.py            # paper campaign + UR10 A and B
    .venv/bin/python bench/calibration.py --no-ur10  # simulated campaign only

Each dataset is split 90/10 (seed 0); calibration is fitted on the 90% and every error is
the position / orientation error on the held-out 10%. "Uncalibrated" is the nominal model
with the dataset's frames (the simulator's believed ``T_W_0``/``T_6_S``; for the UR10 the
importer's AX = ZB frames identification).
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import numpy as np

from kinematics.calibration import calibrate, residual_stats
from kinematics.dataset import Dataset
from kinematics.description import load_description
from kinematics.gap.workflow import GapConfig, run_gap, split
from kinematics.identification.conditions import cell_description
from kinematics.importers.ipa import import_series
from kinematics.model import RobotModel
from sim_sources.cell import simulate
from sim_sources.scenarios import get_scenario

UR10 = Path(__file__).resolve().parents[2] / "shared" / "data" / "ur10-ipa"


def heldout_row(name: str, ds: Dataset) -> list[str]:
    desc = cell_description(load_description(ds.meta.robot), ds)
    train, test = split(len(ds), 0.1, 0)
    tr, te = ds.subset(train), ds.subset(test)
    T_meas = te.measured_poses()
    T_W_0 = np.eye(4) if ds.meta.frame == "base" else np.asarray(ds.meta.T_W_0)
    uncal = residual_stats(T_meas, T_W_0[None] @ RobotModel(desc).fk(te.q()))
    t0 = time.perf_counter()
    cal = calibrate(desc, tr)
    seconds = time.perf_counter() - t0
    after = residual_stats(T_meas, cal.T_W_0[None] @ RobotModel(cal.description).fk(te.q()))
    ident = cal.identifiability
    print(
        f"{name}: kept {len(ident.kept)}, dropped {', '.join(ident.dropped)}; "
        f"condition number {ident.condition_number:.1f}",
        flush=True,
    )
    return [
        name,
        f"{len(tr)}/{len(te)}",
        f"{uncal.mean_mm:.3f} / {uncal.std_mm:.3f} / {uncal.max_mm:.3f}",
        f"{after.mean_mm:.3f} / {after.std_mm:.3f} / {after.max_mm:.3f}",
        f"{uncal.mean_arcmin:.2f} -> {after.mean_arcmin:.2f}",
        f"{len(ident.kept)} / {ident.condition_number:.1f}",
        f"{seconds:.1f}",
    ]


def gap_rows(name: str, ds: Dataset) -> list[str]:
    t0 = time.perf_counter()
    result = run_gap(load_description(ds.meta.robot), ds, GapConfig(start="geometric"))
    seconds = time.perf_counter() - t0
    floor = result.noise_floor.mean_m * 1e3
    stages = "; ".join(f"{s.label}: {s.heldout.mean_mm:.3f}" for s in result.stages)
    named = (
        ", ".join(
            f"{e.effect} (dBIC {e.evidence.delta_bic:.0f}, {100 * e.evidence.explained_share:.1f}%)"
            for e in result.named
        )
        or "none"
    )
    print(f"{name} gap notes: {result.notes}", flush=True)
    return [
        name,
        named,
        stages,
        f"{floor:.4f} ({result.noise_floor.source})",
        "yes" if result.consistent_with_floor else "no",
        f"{seconds:.1f}",
    ]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--no-ur10", action="store_true", help="skip the real UR10 series")
    parser.add_argument("--tmp", default="/tmp", help="where imported UR10 datasets go")
    args = parser.parse_args()
    t0 = time.perf_counter()
    datasets = {"sim paper (3004, seed 0)": simulate(get_scenario("paper"), 3004, 0)}
    print(f"simulated paper campaign in {time.perf_counter() - t0:.1f} s", flush=True)
    if not args.no_ur10:
        for series in ("Series_A", "Series_B"):
            out = Path(args.tmp) / f"ur10_{series[-1].lower()}.parquet"
            datasets[f"UR10 {series}"] = import_series(UR10 / series, out=out).dataset
    print_table(
        [
            "dataset",
            "train/test",
            "uncalibrated mean / std / max mm",
            "calibrated mean / std / max mm",
            "arcmin mean",
            "kept params / cond",
            "fit s",
        ],
        [heldout_row(name, ds) for name, ds in datasets.items()],
    )
    print_table(
        [
            "dataset",
            "named effects",
            "held-out mean mm per stage",
            "noise floor mm",
            "consistent",
            "s",
        ],
        [gap_rows(name, ds) for name, ds in datasets.items()],
    )


def print_table(columns: list[str], rows: list[list[str]]) -> None:
    """A Markdown table on stdout after a blank line, ``columns`` its header."""
    print("\n| " + " | ".join(columns) + " |")
    print("|---" * len(columns) + "|")
    for row in rows:
        print("| " + " | ".join(row) + " |")


if __name__ == "__main__":
    main()
