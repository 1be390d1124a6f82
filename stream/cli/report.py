"""CLI commands of reports: ``report iso9283``.

robocal report iso9283 --data cube.parquet --model model.safetensors --out iso/ --json
"""

from __future__ import annotations

import argparse

from stream.cli._base import CLIUsageError, Command, add_data_argument, add_json_flag, emit


class ReportIso9283(Command):
    name = "report iso9283"
    help = (
        "ISO 9283 pose accuracy AP and repeatability RP (and distance accuracy AD/RD) of a "
        "dataset's repeated poses, before and after compensation: Markdown + PNG"
    )

    def add_arguments(self, parser: argparse.ArgumentParser) -> None:
        add_data_argument(parser)
        parser.add_argument(
            "--model", default=None, help="model snapshot (.safetensors): also after compensation"
        )
        parser.add_argument("--out", default="iso9283", help="folder for iso9283.md and .png")
        parser.add_argument(
            "--tolerance-rad",
            type=float,
            default=1e-4,
            help="commanded joints closer than this (rad, every joint) are the same pose",
        )
        parser.add_argument(
            "--min-cycles", type=int, default=2, help="cycles a pose needs to be reported"
        )
        add_json_flag(parser)

    def take_action(self, args: argparse.Namespace) -> int:
        from kinematics.dataset import read_dataset
        from learner.snapshot import load_snapshot
        from stream.reports.iso9283 import iso9283_report, markdown, write_report

        if args.min_cycles < 2:
            raise CLIUsageError(f"--min-cycles must be >= 2, got {args.min_cycles}")
        ds = read_dataset(args.data)
        model = None if args.model is None else load_snapshot(args.model)
        report = iso9283_report(
            ds,
            model,
            data=args.data,
            model_path=args.model,
            tolerance_rad=args.tolerance_rad,
            min_cycles=args.min_cycles,
        )
        md, png = write_report(report, args.out)
        result = {**report.to_dict(), "markdown": str(md), "png": str(png)}
        emit(result, args.json, markdown(report) + f"\nwrote {md} and {png}")
        return 0


COMMANDS: tuple[type[Command], ...] = (ReportIso9283,)
