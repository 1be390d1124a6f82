"""Benchmark of the hyperparameter search: selected model against the learner's defaults.

Splits the dataset 90/10 (seed 0), identifies the physics base on the 90 % (``--base``), runs
the search on the 90 % (Hyperband; with ``--nop`` again with ``NopPruner``, same seed), and
scores on the 10 % (mm) the selected model as ``robocal hpo`` retrains it against the
learner's default configs trained the same way (the search's trial 0 scores the defaults on
its own folds). Any dataset: the paper campaign or an imported UR10 series.

    .venv/bin/python bench/hpo.py --workers 2           # 30 trials, 5 folds, paper campaign
    .venv/bin/python bench/hpo.py --data /tmp/a.parquet --workers 2   # UR10 Series A

``--small`` narrows the space to 1-3 hidden layers, 16-128 neurons and batches of 32-64 (the
other ranges stay DESIGN's). CPU times are printed beside wall times: the cores are shared.
The dataset is made with ``robocal sim dataset --scenario paper --n 3004 --seed 0`` when absent.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import optuna
import torch

from kinematics.dataset import read_dataset
from learner.base import DEFAULT_BASE, data_frame, make_base
from learner.config import ModelConfig, TrainConfig
from learner.features import FeatureSpec
from learner.hpo import HpoConfig, dataset_arrays, search
from learner.hpo_objective import trial_configs
from learner.hpo_space import SearchSpace, TrialParams, load_space
from learner.hpo_study import open_storage
from learner.metrics import accuracy_report
from learner.model import ErrorModel


def parse_args() -> argparse.Namespace:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--data", default="/tmp/paper.parquet", help="made by robocal sim")
    parser.add_argument("--trials", type=int, default=30)
    parser.add_argument("--folds", type=int, default=5)
    parser.add_argument("--epochs", type=int, default=200, help="max epochs per fold")
    parser.add_argument("--min-epochs", type=int, default=10, help="Hyperband min resource")
    parser.add_argument("--space", default=None, help="search-space TOML (default: DESIGN's)")
    parser.add_argument("--small", action="store_true", help="the narrow space of the docstring")
    parser.add_argument("--default-epochs", type=int, default=TrainConfig().max_epochs)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--threads", type=int, default=1, help="torch threads")
    parser.add_argument("--nop", action="store_true", help="also search with NopPruner")
    parser.add_argument("--workers", type=int, default=1, help="worker processes")
    parser.add_argument("--trial-work", type=float, default=HpoConfig().trial_work)
    parser.add_argument("--base", default=DEFAULT_BASE, help="nominal, geometric, auto, FILE")
    parser.add_argument("--skip-search", action="store_true", help="only the defaults model")
    parser.add_argument("--skip-defaults", action="store_true", help="no defaults model")
    parser.add_argument(
        "--candidate",
        action="append",
        default=[],
        help="JSON of trial parameters (another study's selection) trained like the defaults",
    )
    return parser.parse_args()


def run_search(
    name: str, cfg: HpoConfig, space: SearchSpace, data: tuple, tmp: Path, workers: int
) -> dict:
    """One search on the training split; its times, counts, selection and test accuracy."""
    spec, X, Y, train, test, robot, base = data
    t0, c0 = time.perf_counter(), time.process_time()
    res = search(
        spec,
        X[train],
        Y[train],
        cfg,
        tmp / f"{name}.journal",
        space=space,
        robot=robot,
        base=base,
        workers=workers,
    )
    wall, cpu = time.perf_counter() - t0, time.process_time() - c0
    acc = accuracy_report(res.model, X[test], Y[test]).to_dict()
    storage = open_storage(tmp / f"{name}.journal")
    trial0 = optuna.load_study(study_name=cfg.study, storage=storage).trials[0]
    ranks = sorted(r.value for r in res.top)
    print(
        f"{name}: {wall:.1f} s wall, {cpu:.1f} s cpu, {res.complete} complete, "
        f"{res.pruned} pruned; selected trial {res.selected.number} "
        f"({res.selected.n_weights} weights, {res.retrain_epochs} epochs): "
        f"test mean {acc['mean_mm']:.4f} mm\n{res.table()}",
        flush=True,
    )
    return {
        "wall_s": wall,
        "cpu_s": cpu,
        "complete": res.complete,
        "pruned": res.pruned,
        "failed": res.failed,
        "best": dataclasses.asdict(res.best),
        "selected": dataclasses.asdict(res.selected),
        "retrain_epochs": res.retrain_epochs,
        "trial0": {"params": trial0.params, "state": trial0.state.name, "value": trial0.value},
        "trial0_rank_in_top": ranks.index(trial0.value) if trial0.value in ranks else None,
        "test": acc,
    }


def warm_up(spec: FeatureSpec, X: np.ndarray, Y: np.ndarray) -> None:
    """One tiny fit, so that torch's first-call costs fall outside every timing."""
    model = ErrorModel.create(spec, ModelConfig(hidden_layers=1, neurons=8), TrainConfig(), 0)
    model.fit(X, Y, max_epochs=2)


def trained_like_defaults(
    name: str, data: tuple, model_cfg: ModelConfig, train_cfg: TrainConfig
) -> dict:
    """A model of these configs trained on the 90 % as ``robocal train`` does (10 %
    validation, best epoch, early stopping) and scored on the 10 %."""
    spec, X, Y, train, test, robot, base = data
    t0, c0 = time.perf_counter(), time.process_time()
    seed = train_cfg.seed
    model = ErrorModel.create(spec, model_cfg, train_cfg, seed=seed, robot=robot, base=base)
    torch.manual_seed(seed)
    report = model.fit(X[train], Y[train])
    acc = accuracy_report(model, X[test], Y[test]).to_dict()
    print(
        f"{name}: test mean {acc['mean_mm']:.4f} mm "
        f"({model.n_weights} weights, {report.epochs} epochs)",
        flush=True,
    )
    return {
        "wall_s": time.perf_counter() - t0,
        "cpu_s": time.process_time() - c0,
        "n_weights": model.n_weights,
        "epochs": report.epochs,
        "test": acc,
    }


def main() -> None:
    args = parse_args()
    torch.set_num_threads(args.threads)
    optuna.logging.set_verbosity(optuna.logging.WARNING)
    path = Path(args.data)
    if not path.exists():
        robocal = str(Path(sys.executable).parent / "robocal")
        cmd = ["sim", "dataset", "--scenario", "paper", "--n", "3004", "--seed", "0"]
        subprocess.run([robocal, *cmd, "--out", str(path)], check=True)
    ds = read_dataset(path)
    spec, X, Y = dataset_arrays(ds)
    order = np.random.default_rng(args.seed).permutation(len(X))
    n_test = round(0.1 * len(X))
    test, train = order[:n_test], order[n_test:]
    base = make_base(args.base, spec, X[train], Y[train], data_frame(ds))
    data = (spec, X, Y, train, test, ds.meta.robot, base)
    warm_up(spec, X[:64], Y[:64])
    space = load_space(args.space) if args.space else SearchSpace()
    if args.small:
        space = dataclasses.replace(
            space, hidden_layers=(1, 3), neurons=(16, 128), batch_size=(32, 64)
        )
    cfg = HpoConfig(
        trials=args.trials,
        folds=args.folds,
        max_epochs=args.epochs,
        min_epochs=args.min_epochs,
        trial_work=args.trial_work,
        seed=args.seed,
    )
    uncal = float(np.mean(np.linalg.norm(Y[test, :3], axis=1)) * 1e3)
    print(f"uncalibrated: test mean {uncal:.4f} mm", flush=True)
    results: dict = {
        "data": str(path),
        "n_train": len(train),
        "n_test": n_test,
        "uncalibrated_test_mean_mm": uncal,
        "config": dataclasses.asdict(cfg) | {"space": dataclasses.asdict(space)},
    }
    runs = [] if args.skip_search else [("hyperband", cfg)]
    if args.nop and not args.skip_search:
        runs.append(("nop", dataclasses.replace(cfg, prune=False)))
    with tempfile.TemporaryDirectory() as tmp:
        for name, run_cfg in runs:
            results[name] = run_search(name, run_cfg, space, data, Path(tmp), args.workers)
    full = TrainConfig(seed=args.seed, max_epochs=args.default_epochs)
    if not args.skip_defaults:
        results["defaults"] = trained_like_defaults("learner defaults", data, ModelConfig(), full)
    for k, raw in enumerate(args.candidate):
        model_cfg, train_cfg = trial_configs(TrialParams.from_dict(json.loads(raw)), cfg)
        train_cfg = dataclasses.replace(train_cfg, max_epochs=full.max_epochs)
        results[f"candidate{k}"] = trained_like_defaults(
            f"candidate {raw}", data, model_cfg, train_cfg
        )
    if "nop" in results:
        for key in ("wall", "cpu"):
            saved = 100 * (1 - results["hyperband"][f"{key}_s"] / results["nop"][f"{key}_s"])
            results[f"pruning_saved_{key}_pct"] = saved
            print(f"pruning saved {saved:.1f} % of the {key} time")
    print(json.dumps(results, indent=2, default=float))


if __name__ == "__main__":
    main()
