"""CLI commands of the simulated cell: ``sim dataset``.

robocal sim dataset --scenario paper --n 3004 --seed 0 --out data.parquet
robocal sim dataset --list
"""

from __future__ import annotations

import argparse

from stream.cli._base import CLIUsageError, Command, ProgressBar, add_json_flag, emit


class SimDataset(Command):
    name = "sim dataset"
    help = "simulate a measurement campaign of the simulated cell and write it as a dataset"
    uses_torch = False

    def add_arguments(self, parser: argparse.ArgumentParser) -> None:
        parser.add_argument("--scenario", default="paper", help="scenario name (see --list)")
        parser.add_argument("--n", type=int, default=3004, help="number of measured points")
        parser.add_argument("--seed", type=int, default=0, help="campaign seed (program, noise)")
        parser.add_argument("--out", default=None, help="dataset file to write (.parquet/.csv)")
        parser.add_argument("--scale", type=float, default=None, help="scale every effect")
        parser.add_argument(
            "--noise",
            action=argparse.BooleanOptionalAction,
            default=None,
            help="switch tracker and repeatability noise (default: the scenario's)",
        )
        parser.add_argument(
            "--model",
            default=None,
            help="simulate the robot of a model file from `robocal gap` (calibrated description "
            "+ identified effects) in the scenario's cell",
        )
        parser.add_argument("--list", action="store_true", help="list the scenarios and exit")
        add_json_flag(parser)

    def take_action(self, args: argparse.Namespace) -> int:
        from sim_sources import get_scenario, list_scenarios, scenario_from_model, write_campaign

        if args.list:
            scenarios = list_scenarios()
            text = "\n".join(f"{name:18s} {summary}" for name, summary in scenarios.items())
            emit({"scenarios": scenarios}, args.json, text)
            return 0
        if args.out is None:
            raise CLIUsageError("sim dataset needs --out FILE (or --list)")
        scenario = get_scenario(args.scenario, scale=args.scale, noise=args.noise)
        if args.model is not None:
            scenario = scenario_from_model(args.model, scenario)
        with ProgressBar(total=args.n, desc="simulating", unit="pt") as bar:
            report = write_campaign(scenario, args.n, args.seed, args.out, bar.update)
        acc = report.accuracy
        text = (
            f"{report.scenario}: {report.n} points (seed {report.seed}) -> {report.path}\n"
            f"uncalibrated position error: mean {acc.mean_mm:.3f} mm, std {acc.std_mm:.3f} mm, "
            f"max {acc.max_mm:.3f} mm; noise floor {1e3 * report.noise_floor_m:.4f} mm; "
            f"campaign {report.duration_s / 3600:.1f} h"
        )
        emit(report.to_dict(), args.json, text)
        return 0


COMMANDS: tuple[type[Command], ...] = (SimDataset,)
