"""CLI command ``hpo``: Optuna search over the evidential ensemble.

robocal hpo --data train.parquet --trials 50 --out model.safetensors
robocal hpo --data train.parquet --trials 50 --storage sqlite:///hpo.db --study cell1
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import optuna
from tqdm import tqdm

from kinematics.dataset import read_dataset
from learner.hpo import HpoConfig, run_hpo
from learner.hpo_space import SearchSpace, load_space
from learner.hpo_study import Progress
from stream.cli._base import Command, add_base_argument, add_json_flag, emit


class HpoCommand(Command):
    name = "hpo"
    help = "search hyperparameters (TPE + Hyperband, k-fold CV) and save the selected model"

    def add_arguments(self, parser: argparse.ArgumentParser) -> None:
        parser.add_argument("--data", required=True, help="training dataset (.parquet or .csv)")
        parser.add_argument("--trials", type=int, default=50, help="trials in the whole study")
        parser.add_argument("--timeout", type=float, default=None, help="stop asking after S s")
        parser.add_argument(
            "--storage",
            default=None,
            help="journal file or RDB URL (sqlite:///hpo.db); default: hpo.journal beside --out",
        )
        parser.add_argument("--study", default="robocal-hpo", help="study name in the storage")
        parser.add_argument("--space", default=None, help="TOML file overriding search ranges")
        parser.add_argument("--out", default="hpo-model.safetensors", help="selected snapshot")
        parser.add_argument("--seed", type=int, default=0, help="sampler, folds and weights seed")
        parser.add_argument("--folds", type=int, default=5, help="cross-validation folds")
        parser.add_argument("--epochs", type=int, default=200, help="max epochs per fold")
        parser.add_argument("--min-epochs", type=int, default=10, help="Hyperband min resource")
        parser.add_argument("--top", type=int, default=10, help="select among the N best trials")
        parser.add_argument("--no-prune", action="store_true", help="NopPruner instead")
        add_base_argument(parser)
        add_json_flag(parser)

    def take_action(self, args: argparse.Namespace) -> int:
        cfg = HpoConfig(
            trials=args.trials,
            timeout_s=args.timeout,
            folds=args.folds,
            max_epochs=args.epochs,
            min_epochs=args.min_epochs,
            prune=not args.no_prune,
            top_k=args.top,
            seed=args.seed,
            study=args.study,
        )
        space = load_space(args.space) if args.space else SearchSpace()
        out = Path(args.out)
        storage = args.storage or str(out.parent / "hpo.journal")
        ds = read_dataset(args.data)
        optuna.logging.set_verbosity(optuna.logging.WARNING)  # the bar shows progress
        with tqdm(total=cfg.trials, desc="hpo trials", file=sys.stderr, unit="trial") as bar:

            def on_trial(p: Progress) -> None:
                bar.n = min(p.finished, p.total)
                if p.best_value is not None:
                    bar.set_postfix(best=f"{p.best_value:.4g}", refresh=False)
                bar.refresh()

            result = run_hpo(
                ds, cfg, storage, space=space, out=out, on_trial=on_trial, base=args.base
            )
        s = result.selected
        text = (
            f"study {result.study!r} in {result.storage}: {result.complete} complete, "
            f"{result.pruned} pruned, {result.failed} failed ({result.ran_here} run here, "
            f"{result.wall_s:.1f} s)\n{result.table()}\n"
            f"selected trial {s.number} (cv mse {s.value:.4g}, {s.n_weights} weights), "
            f"retrained {result.retrain_epochs} epochs -> {result.snapshot}\n"
            f"dashboard: optuna-dashboard {result.storage}"
        )
        emit(result.to_dict(), args.json, text)
        return 0


COMMANDS: tuple[type[Command], ...] = (HpoCommand,)
