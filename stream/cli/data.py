"""CLI commands on datasets: ``import ipa``, ``data summary`` and ``data reference-poses``.

robocal import ipa ../shared/data/ur10-ipa/Series_B --out ur10_b.parquet
robocal data summary ur10_b.parquet --hist errors.png --json
robocal data reference-poses program.csv --robot ur10 --n 100 --out first_poses.csv
"""

from __future__ import annotations

import argparse
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from stream.cli._base import Command, ProgressBar, add_json_flag, emit, notice

if TYPE_CHECKING:
    import pandas as pd


class ImportIpa(Command):
    name = "import ipa"
    help = "import a UR10 laser-tracker series folder (ur10-ipa layout) into the dataset format"
    uses_torch = False

    def add_arguments(self, parser: argparse.ArgumentParser) -> None:
        parser.add_argument("folder", help="series folder, e.g. ../shared/data/ur10-ipa/Series_B")
        parser.add_argument("--out", required=True, help="dataset file to write (.parquet/.csv)")
        parser.add_argument("--robot", default="ur10", help="robot description (name or TOML)")
        parser.add_argument(
            "--frames-rows",
            type=int,
            default=None,
            metavar="N",
            help="identify T_W_0 and T_6_S from the first N rows only (default: every row); "
            "for a new day a model is carried into, what its first points know",
        )
        add_json_flag(parser)

    def take_action(self, args: argparse.Namespace) -> int:
        from kinematics.importers.ipa import import_series

        with ProgressBar(total=4, desc="import ipa", unit="stage") as bar:

            def stage_done(stage: str) -> None:
                bar.set_postfix_str(stage, refresh=False)
                bar.update()

            result = import_series(
                args.folder,
                robot=args.robot,
                out=args.out,
                progress=stage_done,
                frames_rows=args.frames_rows,
            )
        fit = result.fit.summary()
        meta = result.dataset.meta
        payload = {
            "series": result.series,
            "out": str(result.path),
            "n": len(result.dataset),
            "robot": meta.robot,
            "frame": meta.frame,
            "time_source": meta.extra["time_source"],
            "T_W_0": meta.T_W_0,
            "T_6_S": meta.T_6_S,
            "noise_floor_m": meta.noise_floor_m,
            "frames_rows": meta.extra.get("frames_rows", len(result.dataset)),
            "fit_mean_mm": fit.mean_mm,
            "fit_max_mm": fit.max_mm,
            "fit_mean_arcmin": fit.mean_arcmin,
            "frame_fit_left_out_rows": meta.extra["frame_fit_left_out_rows"],
        }
        left_out = meta.extra["frame_fit_left_out_rows"]
        note = f"\nrows left out of the frame fit as gross outliers: {left_out}" if left_out else ""
        text = (
            f"{result.series}: {len(result.dataset)} points -> {result.path}\n"
            f"frames fit residual: mean {fit.mean_mm:.3f} mm, max {fit.max_mm:.3f} mm, "
            f"mean {fit.mean_arcmin:.2f} arcmin; time from {meta.extra['time_source']}" + note
        )
        emit(payload, args.json, text)
        return 0


class DataSummary(Command):
    name = "data summary"
    help = "uncalibrated absolute accuracy of a dataset against its nominal robot model"
    uses_torch = False

    def add_arguments(self, parser: argparse.ArgumentParser) -> None:
        parser.add_argument("file", help="dataset file (.parquet or .csv with .meta.json)")
        parser.add_argument("--robot", default=None, help="robot description (default: meta)")
        parser.add_argument("--hist", default=None, help="write a PNG histogram of errors here")
        add_json_flag(parser)

    def take_action(self, args: argparse.Namespace) -> int:
        from kinematics.accuracy import accuracy_summary
        from kinematics.series import read_series

        desc, ds = read_series(args.file, args.robot, notice)
        s = accuracy_summary(ds, desc)
        if args.hist is not None:
            from stream.reports.plots import save_histogram

            title = f"{Path(args.file).name} on {s.robot}"
            save_histogram(s.errors_mm, args.hist, title=title)
        text = (
            f"{args.file}: N = {s.n}\n"
            f"position error  mean {s.mean_mm:.3f} mm, std {s.std_mm:.3f}, "
            f"p95 {s.p95_mm:.3f}, max {s.max_mm:.3f} mm\n"
            f"orientation error  mean {s.mean_arcmin:.2f} arcmin, max {s.max_arcmin:.2f} arcmin"
        )
        emit(s.to_dict(), args.json, text)
        return 0


class ReferencePoses(Command):
    name = "data reference-poses"
    help = "which of a program's poses a new set-up should measure first (D-optimal, in order)"
    uses_torch = False

    def add_arguments(self, parser: argparse.ArgumentParser) -> None:
        parser.add_argument(
            "file", help="the program's poses: .parquet or .csv with joint angles q1..qn (rad)"
        )
        parser.add_argument("--robot", required=True, help="robot description (name, TOML or URDF)")
        parser.add_argument("--n", type=int, default=100, help="how many poses (default 100)")
        parser.add_argument(
            "--first", type=int, default=0, help="the row the robot starts at (default 0)"
        )
        parser.add_argument("--out", required=True, help="CSV to write: row, q1..qn in order")
        add_json_flag(parser)

    def take_action(self, args: argparse.Namespace) -> int:
        import pandas as pd

        from kinematics.description import load_description
        from kinematics.reference import reference_order

        q = joint_angles(Path(args.file))
        order = reference_order(load_description(args.robot), q.to_numpy(float), args.n, args.first)
        poses = pd.concat(
            [pd.Series(order, name="row"), q.iloc[order].reset_index(drop=True)], axis=1
        )
        poses.to_csv(args.out, index=False)
        spans = np.rad2deg(np.ptp(q.to_numpy(float)[order], axis=0))
        result = {"out": args.out, "n": len(order), "rows": order.tolist(), "span_deg": spans}
        text = (
            f"{args.out}: {len(order)} of {len(q)} poses to measure first, in order; "
            f"joint spans {', '.join(f'{s:.0f}' for s in spans)} deg"
        )
        emit(result, args.json, text)
        return 0


def joint_angles(path: Path) -> pd.DataFrame:
    """The columns ``q1..qn`` (rad) of a ``.parquet`` or ``.csv`` file of poses; a one-line
    :class:`DatasetError` where it has none or cannot be read."""
    import pandas as pd

    from kinematics.dataset import joint_columns
    from kinematics.errors import DatasetError

    if path.suffix not in (".parquet", ".csv"):
        raise DatasetError(f"{path}: poses are read from .parquet or .csv, got {path.suffix!r}")
    try:
        table = pd.read_parquet(path) if path.suffix == ".parquet" else pd.read_csv(path)
    except (OSError, ValueError) as exc:
        raise DatasetError(f"{path}: cannot be read: {exc}") from None
    columns = joint_columns(table)
    if not columns:
        raise DatasetError(f"{path}: no joint angle columns q1..qn")
    q = table[columns]
    if not np.isfinite(q.to_numpy(float)).all():
        raise DatasetError(f"{path}: joint angles q1..q{len(columns)} must be finite numbers")
    return q


COMMANDS: tuple[type[Command], ...] = (ImportIpa, DataSummary, ReferencePoses)
