"""CLI commands ``gap`` (the sim-vs-measured discrepancy workflow) and ``calibrate``.

robocal calibrate --data paper.parquet --out calibrated.toml --json  # --prior-mm 0: least squares
robocal gap --data paper.parquet --robot fanuc_m900ib700 --start geometric --report out/ --json
"""

from __future__ import annotations

import argparse
from typing import TYPE_CHECKING

from stream.cli._base import (
    Command,
    ProgressBar,
    add_data_argument,
    add_json_flag,
    emit,
    notice,
)

if TYPE_CHECKING:
    from kinematics.calibration import CalibrationConfig


def add_prior_argument(parser: argparse.ArgumentParser) -> None:
    """``--prior-mm``: the calibration prior (``CalibrationConfig.prior_mm``)."""
    parser.add_argument(
        "--prior-mm",
        type=float,
        default=None,
        help="hold each DH deviation (and effect) to what moves the tool by this much, mm RMS "
        "over the joint limits (default 0.3); 0: plain least squares",
    )


def calibration_config(args: argparse.Namespace, **settings: float) -> CalibrationConfig:
    """The calibration settings of ``args`` (``--prior-mm``) and ``settings``."""
    from kinematics.calibration import CalibrationConfig

    if args.prior_mm is not None:
        settings["prior_mm"] = args.prior_mm or None
    return CalibrationConfig(**settings)


class Gap(Command):
    name = "gap"
    help = "fit a starting model, find where it disagrees with the data and name missing effects"

    def add_arguments(self, parser: argparse.ArgumentParser) -> None:
        add_data_argument(parser, robot=True)
        parser.add_argument(
            "--start",
            default="geometric",
            help="starting model: geometric (calibrated DH + frames) or nominal",
        )
        parser.add_argument("--test-fraction", type=float, default=0.2, help="held-out share")
        parser.add_argument("--seed", type=int, default=0, help="seed of the held-out split")
        parser.add_argument("--level", type=float, default=0.01, help="test level (corrected)")
        parser.add_argument("--report", default=None, help="folder for gap.md, PNGs, .rrd, model")
        add_prior_argument(parser)
        add_json_flag(parser)

    def take_action(self, args: argparse.Namespace) -> int:
        from kinematics.gap.files import gap_from_files
        from kinematics.gap.workflow import GapConfig

        config = GapConfig(
            start=args.start,
            test_fraction=args.test_fraction,
            seed=args.seed,
            level=args.level,
            calibration=calibration_config(args),
        )
        with ProgressBar(desc="gap", unit="step") as bar:

            def progress(message: str) -> None:
                bar.set_postfix_str(message)
                bar.update()

            result = gap_from_files(args.data, args.robot, config, progress, notice)
        files = None
        if args.report is not None:
            from stream.reports.gap import write_report

            files = write_report(result, args.report)
        out = result.to_dict()
        if files is not None:
            out["report"] = {
                "markdown": str(files.markdown),
                "recording": str(files.recording),
                "model": str(files.model),
            }
        before, after = out["before"], out["after"]
        named = ", ".join(e["effect"] for e in out["named_effects"]) or "none"
        text = (
            f"{result.robot}, start {result.start}: named effects: {named}\n"
            f"held-out mean residual {before['mean_mm']:.4f} mm -> {after['mean_mm']:.4f} mm "
            f"(noise floor {out['noise_floor_mm']:.4f} mm, {out['noise_floor_source']})\n"
            f"regions disagreeing before: {len(out['disagreement'])}; consistent with the noise "
            f"floor after: {'yes' if out['consistent_with_noise_floor'] else 'no'}"
            + "".join(f"\nnot named: {e['message']}" for e in out["unnamed_corrections"])
            + "".join(
                f"\nnot formed: {c['effect']} ({c['why']})" for c in out["candidates_not_formed"]
            )
            + ("".join(f"\nnote: {n}" for n in out["notes"]))
            + (f"\nreport: {files.markdown}" if files is not None else "")
        )
        emit(out, args.json, text)
        return 0


class Calibrate(Command):
    name = "calibrate"
    help = "classical geometric calibration (identifiable DH deviations with base/tool frames)"

    def add_arguments(self, parser: argparse.ArgumentParser) -> None:
        add_data_argument(parser, robot=True)
        parser.add_argument("--out", default=None, help="write the calibrated model TOML here")
        parser.add_argument("--rank-rtol", type=float, default=1e-4, help="QR drop tolerance")
        add_prior_argument(parser)
        add_json_flag(parser)

    def take_action(self, args: argparse.Namespace) -> int:
        from kinematics.gap.files import calibrate_from_files

        config = calibration_config(args, rank_rtol=args.rank_rtol)
        result = calibrate_from_files(args.data, args.robot, config, notice)
        if args.out is not None:
            from stream.reports.gap import write_calibrated_model

            write_calibrated_model(result, args.out)
        r = result.residual
        ident = result.identifiability
        text = (
            f"{result.description.name}: {len(ident.kept)} parameters identified, "
            f"{len(ident.dropped)} dropped ({', '.join(ident.dropped)}); "
            f"condition number {ident.condition_number:.1f}\n"
            f"residual mean {r.mean_mm:.4f} mm, RMS {r.rms_mm:.4f}, max {r.max_mm:.4f} mm, "
            f"mean {r.mean_arcmin:.3f} arcmin" + (f"\nwrote {args.out}" if args.out else "")
        )
        emit(result.to_dict(), args.json, text)
        return 0


COMMANDS: tuple[type[Command], ...] = (Gap, Calibrate)
