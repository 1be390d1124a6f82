"""CLI commands of the learner: ``train``, ``continual``, ``evaluate``, ``experiment paper``.

robocal train --data paper.parquet --out model.safetensors --base best
robocal continual --data paper.parquet --memory 500 --batch 100 --out cont.safetensors
robocal continual --from cont.safetensors --data day2.parquet --test-fraction 0 --out c2.safetensors
robocal evaluate --model model.safetensors --data paper.parquet --json
robocal experiment paper --data paper.parquet --out study/ --quick
"""

from __future__ import annotations

import argparse
from pathlib import Path
from typing import TYPE_CHECKING

from learner.config import (
    BASE_KINDS,
    SELECTED_BASE,
    STRATEGIES,
    STREAM_BASE_KINDS,
    ContinualConfig,
    TrainConfig,
)
from stream.cli._base import (
    CLIUsageError,
    Command,
    ProgressBar,
    add_base_argument,
    add_data_argument,
    add_json_flag,
    emit,
    read_data,
)

if TYPE_CHECKING:
    from learner.workflow import ContinualResult, TrainResult


def _report_text(title: str, r: dict) -> str:
    return (
        f"{title}: mean {r['mean_mm']:.4f} mm (std {r['std_mm']:.4f}, p95 {r['p95_mm']:.4f}, "
        f"max {r['max_mm']:.4f}), {r['mean_arcmin']:.3f} arcmin, improvement "
        f"{r['improvement_pct']:.1f}% over uncalibrated {r['uncalibrated_mean_mm']:.4f} mm; "
        f"90% interval covers {100 * r['coverage_90']:.1f}% "
        f"(width {r['interval_width_90_mm']:.4f} mm)"
    )


def _add_split(parser: argparse.ArgumentParser) -> None:
    add_data_argument(parser)
    parser.add_argument("--test-fraction", type=float, default=0.1, help="held-out share")
    parser.add_argument("--seed", type=int, default=0, help="split, weights and batch order")


class Train(Command):
    name = "train"
    help = "batch-train an evidential error model on a dataset and report its test accuracy"

    def add_arguments(self, parser: argparse.ArgumentParser) -> None:
        _add_split(parser)
        parser.add_argument("--out", required=True, help="model snapshot to write (.safetensors)")
        parser.add_argument("--max-epochs", type=int, default=TrainConfig().max_epochs)
        parser.add_argument(
            "--drift-fraction",
            type=float,
            default=TrainConfig().drift_fraction,
            help="the last share of the training points in time that a second training holds "
            "out to measure how much wider a later day needs the intervals (0: not measured)",
        )
        add_base_argument(parser, SELECTED_BASE, (*BASE_KINDS, SELECTED_BASE))
        add_json_flag(parser)

    def take_action(self, args: argparse.Namespace) -> int:
        from learner.carry import position_factor
        from learner.workflow import train_on_dataset
        from stream.reports.learner import write_trained

        ds = read_data(args)
        cfg = TrainConfig(
            seed=args.seed, max_epochs=args.max_epochs, drift_fraction=args.drift_fraction
        )
        with ProgressBar(total=cfg.max_epochs, desc="train", unit="epoch") as bar:

            def progress(epoch: int, val_mse: float) -> None:
                if epoch < bar.n:  # the next base's fit (--base best), then the drift's
                    bar.reset()
                bar.update()
                bar.set_postfix(val_mse=f"{val_mse:.4g}")

            result = train_on_dataset(
                ds,
                test_fraction=args.test_fraction,
                seed=args.seed,
                train_cfg=cfg,
                on_epoch=progress,
                base=args.base,
            )
        write_trained(result, args.out)
        out = {
            "model": args.out,
            "n_train": result.n_train,
            "epochs": result.report.epochs,
            "n_weights": result.model.n_weights,
            "drift_scale": [round(float(s), 3) for s in result.model.drift_scale],
        }
        later = position_factor(result.model.drift_scale)
        text = (
            f"model -> {args.out} ({result.n_train} points, {result.report.epochs} epochs, "
            f"base {result.model.base_kind}; a later day needs its intervals {later:.1f} x wider)"
        )
        return _emit_learned(result, out, text, args.json)


#: The :class:`ContinualConfig` fields that are options of ``continual`` (default: the
#: config's), with their help.
_CONTINUAL_OPTIONS = {
    "memory": "N_m",
    "batch": "n_B",
    "init": "points of model 0",
    "strategy": None,
    "epochs_per_update": None,
    "update_points": "memory points over which an update trains every epoch (fewer above)",
    "refresh_growth": "train a fresh network on the memory each time the points grow by this "
    "factor (0: never)",
    "frame_prior_mm": "with --from: how far the base's frames may move on the first points (mm)",
    "moved_frame_prior_mm": "with --from: the same once those points show a moved tracker/tool",
    "day_frame_points": "with --from: fit the frames again on up to this many of the day's points",
    "day_refresh_growth": "with --from: a fresh network each time the day's points grow by this "
    "factor (0: never)",
}


class Continual(Command):
    name = "continual"
    help = "stream a dataset's training split through continual learning; write model and curve"

    def add_arguments(self, parser: argparse.ArgumentParser) -> None:
        _add_split(parser)
        defaults = ContinualConfig()
        for name, what in _CONTINUAL_OPTIONS.items():
            default = getattr(defaults, name)
            parser.add_argument(
                f"--{name.replace('_', '-')}",
                type=type(default),
                default=default,
                choices=STRATEGIES if name == "strategy" else None,
                help=what,
            )
        parser.add_argument("--out", required=True, help="final model snapshot (.safetensors)")
        parser.add_argument(
            "--from",
            dest="start",
            default=None,
            help="go on from this model (with its replay memory when its .state.safetensors is "
            "beside it); its frames are re-identified from the first --init points",
        )
        parser.add_argument(
            "--new-setup",
            action="store_true",
            help="with --from: the tracker was set up anew for this day (its frames from its "
            "first points, e.g. import ipa --frames-rows): fit its frame freely, hold the tool",
        )
        parser.add_argument(
            "--reference-program",
            action="store_true",
            help="with --from: the first --init points are a reference program spread over the "
            "workspace (data reference-poses): fit the geometry on them too, not only the frames",
        )
        add_base_argument(parser, ContinualConfig().base, STREAM_BASE_KINDS)
        add_json_flag(parser)

    def take_action(self, args: argparse.Namespace) -> int:
        from learner.continual import load_learner
        from learner.continual_records import prequential
        from learner.workflow import continual_on_dataset
        from stream.reports.learner import write_continual

        if args.start is None and (args.new_setup or args.reference_program):
            flag = "--new-setup" if args.new_setup else "--reference-program"
            raise CLIUsageError(f"{flag} describes a day carried from a model: give --from MODEL")
        ds = read_data(args)
        options = {n: getattr(args, n) for n in _CONTINUAL_OPTIONS}
        cfg = ContinualConfig(
            **options,
            new_setup=args.new_setup,
            reference_program=args.reference_program,
            seed=args.seed,
        )
        start = None if args.start is None else load_learner(args.start, cfg)
        n_updates = 1 + -(
            -max(0, round(len(ds) * (1 - args.test_fraction)) - cfg.init) // cfg.batch
        )
        with ProgressBar(total=n_updates, desc="continual", unit="update") as bar:
            result = continual_on_dataset(
                ds,
                cfg,
                test_fraction=args.test_fraction,
                seed=args.seed,
                train_cfg=TrainConfig(seed=args.seed),
                on_update=lambda m: bar.update(),
                base=None if start is not None else args.base,
                start=start,
            )
        csv_path, png_path = write_continual(result, args.out)
        out = {
            "model": args.out,
            "curve_csv": str(csv_path),
            "curve_png": str(png_path),
            "updates": len(result.updates),
            "train_time_s": result.total_time_s,
        }
        text = (
            f"model -> {args.out}; curve -> {csv_path}, {png_path} ({len(result.updates)} "
            f"updates, {result.total_time_s:.1f} s training)"
        )
        out["prequential"] = preq = prequential(result.updates)
        text += (
            f"\nprequential (each batch before it was learned, {preq['n_points']} points): "
            f"mean {preq['mean_mm']:.3f} mm, 90% coverage {preq['coverage_90']:.2f}"
        )
        if result.day_past_envelope is not None:
            out["day_past_envelope"] = result.day_past_envelope
            text += (
                f"\n{100 * result.day_past_envelope:.1f}% of this day's poses lay past the joint "
                f"angles or temperatures {args.start} was trained on"
            )
        return _emit_learned(result, out, text, args.json)


def _emit_learned(
    result: TrainResult | ContinualResult, out: dict, text: str, as_json: bool
) -> int:
    """Print what ``train``/``continual`` learned: ``out`` and ``text`` with the model's
    physics base and its test report (when a test split was held out); exit code 0."""
    base = result.model.base
    test = result.test.to_dict() if result.test else {}
    out = {
        **out,
        "base": {"kind": result.model.base_kind, "note": "" if base is None else base.note},
        "test": test,
    }
    if out["base"]["note"]:
        text += f"\nbase: {out['base']['note']}"
    if test:
        text += "\n" + _report_text("test", test)
    emit(out, as_json, text)
    return 0


class Evaluate(Command):
    name = "evaluate"
    help = "accuracy and interval calibration of a model snapshot on a dataset"

    def add_arguments(self, parser: argparse.ArgumentParser) -> None:
        parser.add_argument("--model", required=True, help="model snapshot (.safetensors)")
        add_data_argument(parser)
        add_json_flag(parser)

    def take_action(self, args: argparse.Namespace) -> int:
        from learner.metrics import accuracy_report, envelope_report
        from learner.snapshot import load_snapshot
        from learner.workflow import evaluation_points

        model = load_snapshot(args.model)
        X, Y = evaluation_points(model, read_data(args))
        report = accuracy_report(model, X, Y).to_dict()
        report["envelope"] = envelope = envelope_report(model, X, Y)
        text = _report_text(f"{args.data} ({report['n']} points)", report)
        if envelope["n_outside"]:
            text += (
                f"\n{100 * envelope['outside_share']:.1f}% of the poses lie past the joint angles"
                f" ({envelope['n_past_joints']}) or only the temperatures"
                f" ({envelope['n_past_temperatures_only']}) the model was trained on (compensation"
                " does not trust them)"
            )
            if envelope["inside"] is not None:
                text += "; " + _report_text("the others", envelope["inside"])
        report["unverified"] = model.unverified
        if model.unverified:
            text += f"\nunverified: {model.unverified} (compensation trusts none of its answers)"
        emit(report, args.json, text)
        return 0


class ExperimentPaper(Command):
    name = "experiment paper"
    help = "the reference study: feature ablation, training-set size, continual vs batch, SGPR"

    def add_arguments(self, parser: argparse.ArgumentParser) -> None:
        add_data_argument(parser)
        parser.add_argument("--out", default="paper_study", help="folder for table and plots")
        parser.add_argument("--seed", type=int, default=0)
        parser.add_argument("--quick", action="store_true", help="small grid, few epochs")
        add_json_flag(parser)

    def take_action(self, args: argparse.Namespace) -> int:
        from learner.experiment import StudyConfig, run_paper_study
        from stream.reports.learner import write_study

        ds = read_data(args)
        Path(args.out).mkdir(parents=True, exist_ok=True)  # a bad folder fails before the runs
        cfg = StudyConfig.quick(seed=args.seed) if args.quick else StudyConfig(seed=args.seed)
        with ProgressBar(total=cfg.n_runs, desc="experiment", unit="run") as bar:
            study = run_paper_study(ds, cfg, on_run=lambda name: bar.update())
        out_dir = write_study(study, args.out)
        emit({**study.to_dict(), "out_dir": str(out_dir)}, args.json, study.markdown)
        return 0


COMMANDS: tuple[type[Command], ...] = (Train, Continual, Evaluate, ExperimentPaper)
