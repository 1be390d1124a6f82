"""CLI command ``hpo``: Optuna search over the evidential ensemble.

robocal hpo --data train.parquet --trials 50 --out model.safetensors
robocal hpo --data train.parquet --trials 50 --workers 2 --dashboard
robocal hpo --data train.parquet --trials 50 --storage postgresql://user@db-host/robocal
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path
from typing import TYPE_CHECKING

from learner.hpo_config import TRIAL_WORK, HpoConfig, default_threads
from stream.cli._base import (
    CLIUsageError,
    Command,
    ProgressBar,
    add_base_argument,
    add_json_flag,
    emit,
    read_data,
)

if TYPE_CHECKING:
    from learner.hpo_study import Progress


class HpoCommand(Command):
    name = "hpo"
    help = "search hyperparameters (TPE + Hyperband, k-fold CV) and save the selected model"

    def add_arguments(self, parser: argparse.ArgumentParser) -> None:
        parser.add_argument("--data", required=True, help="training dataset (.parquet or .csv)")
        parser.add_argument("--trials", type=int, default=50, help="trials in the whole study")
        parser.add_argument(
            "--timeout", type=float, default=None, help="stop after S s (a running trial too)"
        )
        parser.add_argument(
            "--storage",
            default=None,
            help="journal file or RDB URL (postgresql://user:pw@host/db to share one study "
            "between machines, sqlite:///hpo.db); default: hpo.journal beside --out",
        )
        parser.add_argument(
            "--workers", type=int, default=1, help="worker processes on this machine"
        )
        parser.add_argument(
            "--threads", type=int, default=None, help="torch threads per worker (cores/workers)"
        )
        parser.add_argument("--study", default="robocal-hpo", help="study name in the storage")
        parser.add_argument("--space", default=None, help="TOML file overriding search ranges")
        parser.add_argument("--out", default="hpo-model.safetensors", help="selected snapshot")
        parser.add_argument("--seed", type=int, default=0, help="sampler, folds and weights seed")
        parser.add_argument("--folds", type=int, default=5, help="cross-validation folds")
        parser.add_argument("--epochs", type=int, default=200, help="max epochs per fold")
        parser.add_argument(
            "--trial-work",
            type=float,
            default=TRIAL_WORK,
            help="work per trial capping its epochs (weight x row passes; inf: no cap)",
        )
        parser.add_argument(
            "--sequential-folds", action="store_true", help="train folds one after the other"
        )
        parser.add_argument(
            "--min-epochs", type=int, default=None, help="Hyperband min resource (10, <= epochs)"
        )
        parser.add_argument("--top", type=int, default=10, help="select among the N best trials")
        parser.add_argument("--no-prune", action="store_true", help="NopPruner instead")
        parser.add_argument(
            "--dashboard",
            action="store_true",
            help="serve optuna-dashboard on the study while it runs (extra: dashboard)",
        )
        parser.add_argument("--dashboard-port", type=int, default=8080, help="dashboard port")
        add_base_argument(parser)
        add_json_flag(parser)

    def take_action(self, args: argparse.Namespace) -> int:
        import optuna
        import torch

        from learner.hpo import run_hpo
        from learner.hpo_dashboard import start_dashboard
        from learner.hpo_space import SearchSpace, load_space
        from learner.hpo_study import is_url, open_storage

        cfg = HpoConfig(
            trials=args.trials,
            timeout_s=args.timeout,
            folds=args.folds,
            max_epochs=args.epochs,
            min_epochs=args.min_epochs if args.min_epochs is not None else min(10, args.epochs),
            trial_work=args.trial_work,
            batched_folds=not args.sequential_folds,
            prune=not args.no_prune,
            top_k=args.top,
            seed=args.seed,
            study=args.study,
        )
        space = load_space(args.space) if args.space else SearchSpace()
        out = Path(args.out)
        storage = args.storage or str(out.parent / "hpo.journal")
        if args.workers < 1:
            raise CLIUsageError(f"--workers must be >= 1, got {args.workers}")
        if args.threads is not None and args.threads < 1:
            raise CLIUsageError(f"--threads must be >= 1, got {args.threads}")
        if is_url(storage):  # an unreachable or malformed database fails before any work
            open_storage(storage)
        if args.dashboard:
            url = start_dashboard(storage, port=args.dashboard_port)
            print(f"optuna-dashboard on {url}", file=sys.stderr)
        torch.set_num_threads(args.threads or default_threads(args.workers))
        ds = read_data(args)
        optuna.logging.set_verbosity(optuna.logging.WARNING)  # the bar shows progress
        with ProgressBar(total=cfg.trials, desc="hpo trials", unit="trial") as bar:

            def on_trial(p: Progress) -> None:
                bar.update(min(p.finished, p.total) - bar.n)
                if p.best_value is not None:
                    bar.set_postfix(best=f"{p.best_value:.4g}", refresh=False)
                bar.refresh()

            result = run_hpo(
                ds,
                cfg,
                storage,
                space=space,
                out=out,
                on_trial=on_trial,
                base=args.base,
                workers=args.workers,
            )
        s = result.selected
        text = (
            f"study {result.study!r} in {result.storage}: {result.complete} complete, "
            f"{result.pruned} pruned, {result.failed} failed ({result.ran_here} run here of "
            f"{result.workers} worker(s), "
            f"{result.wall_s:.1f} s)\n{result.table()}\n"
            f"selected trial {s.number} (cv mse {s.value:.4g}, {s.n_weights} weights), "
            f"retrained {result.retrain_epochs} epochs -> {result.snapshot}\n"
            f"dashboard: optuna-dashboard {result.storage}"
        )
        emit(result.to_dict(), args.json, text)
        return 0


COMMANDS: tuple[type[Command], ...] = (HpoCommand,)
