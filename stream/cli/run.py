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

from stream.cli._base import Command, ProgressBar, add_json_flag, emit

if TYPE_CHECKING:
    from stream.config import DashboardConfig


class RunCommand(Command):
    name = "run"
    help = "run the pipeline stages of a TOML config until SIGTERM/SIGINT"

    def add_arguments(self, parser: argparse.ArgumentParser) -> None:
        parser.add_argument("--config", required=True, help="daemon TOML config")
        parser.add_argument(
            "--speed",
            type=float,
            default=None,
            help="x recorded time of the config's dataset and sim sources (0: as fast as possible)",
        )

    def take_action(self, args: argparse.Namespace) -> int:
        from stream.config import dashboard_index, load_config
        from stream.daemon import run_until_signal

        cfg = load_config(args.config)
        if args.speed is not None:
            from dataclasses import replace

            from stream.sources.config import with_speed

            cfg = replace(cfg, sources=with_speed(cfg.sources, args.speed))
        if cfg.dashboard is not None and cfg.dashboard.serve:
            for r in cfg.robots:
                if "dashboard" in r.stages:
                    print_dashboard_url(cfg.dashboard, r.name, dashboard_index(cfg, r.name))
        return run_until_signal(cfg)


def print_dashboard_url(dc: DashboardConfig, robot: str = "", index: int = 0) -> None:
    """One line on stderr with the URL that opens a robot's live dashboard in a browser (the
    ``index``-th robot with a dashboard is served on the configured ports + ``index``)."""
    from stream.dashboard import viewer_url

    url = viewer_url(dc.host, dc.web_port + index, dc.grpc_port + index)
    print(f"dashboard{' ' + robot if robot else ''}: {url}", file=sys.stderr)


class ReplayCommand(Command):
    name = "replay"
    help = "republish an MCAP recording on the bus, streamed from the file (constant memory)"
    uses_torch = False

    def add_arguments(self, parser: argparse.ArgumentParser) -> None:
        parser.add_argument(
            "mcap", nargs="+", help="recording(s) made by the recorder (the parts, in order)"
        )
        parser.add_argument("--speed", type=float, default=None, help="x real time (default: max)")
        parser.add_argument(
            "--topics",
            default="joints,tracker,temperature",
            help="comma-separated streams (joints, tracker, temperature, model, ...) or full keys "
            "to republish (default: the source streams)",
        )
        parser.add_argument("--start", type=float, default=None, help="s after the first message")
        parser.add_argument("--end", type=float, default=None, help="s after the first message")
        parser.add_argument(
            "--loop",
            action="store_true",
            help="replay again and again until Ctrl-C, each pass shifted in t and seq",
        )
        parser.add_argument(
            "--connect", action="append", default=[], help="endpoint, e.g. tcp/127.0.0.1:7447"
        )
        parser.add_argument(
            "--wait-subscribers",
            type=float,
            default=10.0,
            help="s to wait for a subscriber on each key before it is replayed (0: none)",
        )
        add_json_flag(parser)

    def take_action(self, args: argparse.Namespace) -> int:
        from stream.bus import BusConfig
        from stream.replay import ReplayOptions, check_recordings, replay_files

        options = ReplayOptions(
            speed=args.speed,
            topics=tuple(t.strip() for t in args.topics.split(",") if t.strip()),
            start_s=args.start,
            end_s=args.end,
            loops=None if args.loop else 1,
            wait_subscribers_s=args.wait_subscribers,
        )
        bus = BusConfig(connect=tuple(args.connect), multicast_scouting=not args.connect)
        total = check_recordings(args.mcap)
        with ProgressBar(
            total=total,
            unit="B",
            unit_scale=True,
            desc="replay",
            disable=args.json,
        ) as bar:
            seen = [0, 0]  # bytes shown, pass

            def progress(done: int, k: int) -> None:
                if k != seen[1]:  # a new pass of --loop
                    seen[:] = [0, k]
                    bar.reset(total)
                    bar.set_postfix_str(f"pass {k + 1}")
                if done - seen[0] >= 1 << 20 or done == total:
                    bar.update(done - seen[0])
                    seen[0] = done

            result = replay_files(args.mcap, bus, options, on_progress=progress)
        out = {"mcap": args.mcap, **result.__dict__}
        text = f"republished {result.published} samples ({result.passes} pass(es))" + "".join(
            f"\n{p}: unfinished (recorder killed?), replayed up to its last complete chunk"
            for p in result.truncated
        )
        if result.unheard:
            text += f"\nnobody subscribed to {', '.join(result.unheard)} in time"
        emit(out, args.json, text + ("\nstopped" if result.stopped else ""))
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
        from stream.config import DashboardConfig
        from stream.demo import run_demo

        if args.serve:
            print_dashboard_url(DashboardConfig(serve=True))
        with ProgressBar(total=args.n, unit="pt", desc="demo") as bar:
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
