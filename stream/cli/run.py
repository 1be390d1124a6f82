"""CLI commands of the live pipeline: ``run`` (daemon) and ``demo``.

robocal run --config deploy/robocal.example.toml
robocal demo --out out --n 1000 --seed 0 --json
robocal demo --serve          # prints the URL that opens the live dashboard in a browser
"""

from __future__ import annotations

import argparse
import sys
from dataclasses import asdict
from typing import TYPE_CHECKING

from stream.cli._base import CLIUsageError, Command, add_json_flag, emit

if TYPE_CHECKING:
    from stream.config import DashboardConfig


class RunCommand(Command):
    name = "run"
    help = "run the pipeline stages of a TOML config until SIGTERM/SIGINT"

    def add_arguments(self, parser: argparse.ArgumentParser) -> None:
        parser.add_argument("--config", required=True, help="daemon TOML config")

    def take_action(self, args: argparse.Namespace) -> int:
        from stream.config import load_config
        from stream.daemon import run_until_signal

        cfg = load_config(args.config)
        if cfg.dashboard is not None and cfg.dashboard.serve:
            print_dashboard_url(cfg.dashboard)
        return run_until_signal(cfg)


def print_dashboard_url(dc: DashboardConfig) -> None:
    """One line on stderr with the URL that opens the live dashboard in a browser."""
    from stream.dashboard import viewer_url

    print(f"dashboard: {viewer_url(dc.host, dc.web_port, dc.grpc_port)}", file=sys.stderr)


class ReplayCommand(Command):
    name = "replay"
    help = "republish the source streams of an MCAP recording on the bus"

    def add_arguments(self, parser: argparse.ArgumentParser) -> None:
        parser.add_argument("mcap", help="recording made by the recorder stage")
        parser.add_argument("--speed", type=float, default=None, help="x real time (default: max)")
        parser.add_argument(
            "--connect", action="append", default=[], help="endpoint, e.g. tcp/127.0.0.1:7447"
        )
        add_json_flag(parser)

    def take_action(self, args: argparse.Namespace) -> int:
        from stream.bus import BusConfig
        from stream.mcap_io import replay_file

        if args.speed is not None and not args.speed > 0:
            raise CLIUsageError(f"--speed must be > 0, got {args.speed}")
        bus = BusConfig(connect=tuple(args.connect), multicast_scouting=not args.connect)
        n = replay_file(args.mcap, bus, args.speed)
        emit({"published": n, "mcap": args.mcap}, args.json, f"republished {n} samples")
        return 0


class DemoCommand(Command):
    name = "demo"
    help = "stream the simulated reference campaign through the pipeline; print the accuracy"

    def add_arguments(self, parser: argparse.ArgumentParser) -> None:
        parser.add_argument("--out", default="out", help="folder for robocal.rrd, robocal.mcap")
        parser.add_argument(
            "--n", type=int, default=3004, help="points in the campaign (the reference: 3004)"
        )
        parser.add_argument("--seed", type=int, default=0, help="campaign and training seed")
        parser.add_argument(
            "--serve",
            action="store_true",
            help="serve the live dashboard while the demo runs and print its URL",
        )
        add_json_flag(parser)

    def take_action(self, args: argparse.Namespace) -> int:
        from tqdm import tqdm

        from stream.config import DashboardConfig
        from stream.demo import run_demo

        if args.serve:
            print_dashboard_url(DashboardConfig(serve=True))
        with tqdm(total=args.n, unit="pt", file=sys.stderr, desc="demo") as bar:
            result = run_demo(
                args.out, args.n, args.seed, lambda k: bar.update(k - bar.n), serve=args.serve
            )
        learned, comp = result.learned, result.compensation
        reached = comp["reached_after_mean_mm"]
        pol = comp["policy"]
        reached_mm = "none" if reached is None else f"{reached:.3f} mm"
        text = (
            f"{result.n_points} points streamed ({result.samples_published} samples), "
            f"model v{result.model_version}, {result.n_test} held-out points:\n"
            f"  uncalibrated  mean {result.uncalibrated_mean_mm:.3f} mm, "
            f"max {result.uncalibrated_max_mm:.3f} mm\n"
            f"  learned       mean {learned['mean_mm']:.3f} mm, max {learned['max_mm']:.3f} mm "
            f"({learned['improvement_pct']:.1f}% better), 90% coverage "
            f"{learned['coverage_90']:.2f}\n"
            f"  compensated   {comp['n']} held-out commands on the true robot: "
            f"{comp['before_mean_mm']:.3f} mm -> {comp['after_mean_mm']:.3f} mm mean error\n"
            f"                {comp['reached']} of them reach the target ({reached_mm}); the "
            f"largest solver residual left is {comp['max_residual_mm']:.3f} mm\n"
            f"                policy {pol['name']} ([compensation] policy) on the "
            f"{pol['applied']} the solver could not land: {pol['untrusted']} untrusted, largest "
            f"residual {pol['max_residual_mm']:.3f} mm\n"
            f"  wrote {result.rrd} and {result.mcap} in {result.elapsed_s:.1f} s"
        )
        emit(asdict(result), args.json, text)
        return 0


COMMANDS: tuple[type[Command], ...] = (RunCommand, ReplayCommand, DemoCommand)
