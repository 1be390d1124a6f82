"""Speed of the hyperparameter search (issue 17): tiny study with a resume, batched against
sequential folds in one run, and trials per hour with 1 and 2 workers.

    .venv/bin/python bench/hpo_speed.py tiny     # hpo --trials 3, killed after 40 s, resumed
    .venv/bin/python bench/hpo_speed.py folds    # same trials: folds batched, then sequential
    .venv/bin/python bench/hpo_speed.py workers --trials 6  # trials/hour, --workers 1 then 2

The data is ``robocal sim dataset --scenario paper --n 300 --seed 0`` (made when absent).
Wall times on a shared machine: the load average is printed beside them.
"""

from __future__ import annotations

import argparse
import json
import os
import signal
import subprocess
import sys
import tempfile
import time
from dataclasses import asdict
from pathlib import Path

import optuna
import torch

from kinematics.dataset import read_dataset
from learner.base import data_frame, make_base
from learner.config import ModelConfig, TrainConfig
from learner.hpo import HpoConfig, dataset_arrays
from learner.hpo_objective import cv_objective
from learner.hpo_space import SearchSpace, TrialParams, suggest
from learner.hpo_study import make_study

ROBOCAL = str(Path(sys.executable).parent / "robocal")
DEFAULT_SHAPE = TrialParams(
    hidden_layers=ModelConfig().hidden_layers,
    neurons=ModelConfig().neurons,
    activation=ModelConfig().activation,
    batch_size=TrainConfig().batch_size,
    lr=TrainConfig().lr,
    weight_decay=TrainConfig().weight_decay,
    dropout=0.0,
)


def load() -> str:
    return f"{os.getloadavg()[0]:.2f}"


def hpo(data: str, storage: str, *extra: str) -> list[str]:
    return [ROBOCAL, "hpo", "--data", data, "--storage", storage, "--json", *extra]


def tiny(data: str, stop_after: float) -> dict:
    """The issue's tiny study: 3 trials, killed (SIGTERM) after ``stop_after`` s, resumed."""
    with tempfile.TemporaryDirectory() as tmp:
        cmd = hpo(data, f"{tmp}/s.journal", "--trials", "3", "--out", f"{tmp}/m.safetensors")
        t0 = time.perf_counter()
        first = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.DEVNULL)
        try:
            first.wait(timeout=stop_after)
        except subprocess.TimeoutExpired:
            first.send_signal(signal.SIGTERM)  # a crash: its running trial is redone
            first.wait()
        t1 = time.perf_counter()
        done = subprocess.run(cmd, capture_output=True, text=True, check=True)
        t2 = time.perf_counter()
    report = json.loads(done.stdout)
    return {
        "first_s": t1 - t0,
        "resume_s": t2 - t1,
        "total_s": t2 - t0,
        "complete": report["complete"],
        "pruned": report["pruned"],
        "failed": report["failed"],
        "ran_in_resume": report["ran_here"],
        "load": load(),
    }


def folds(data: str, seed: int) -> dict:
    """The tiny study's three trials (DESIGN's space, seed 0) and the learner's default shape,
    each trained batched and sequential in turn in this process, at the same epochs."""
    ds = read_dataset(data)
    spec, X, Y = dataset_arrays(ds)
    base = make_base("geometric", spec, X, Y, data_frame(ds))
    study = make_study(optuna.storages.InMemoryStorage(), "f", seed=seed, max_resource=200)
    points = []
    for _ in range(3):
        trial = study.ask()
        points.append(suggest(trial, SearchSpace()))
        study.tell(trial, 1.0)
    points.append(DEFAULT_SHAPE)
    rows = []
    for p in points:
        timing = {}
        for batched in (True, False):
            cfg = HpoConfig(trials=1, folds=5, batched_folds=batched, seed=seed)
            fixed = optuna.trial.FixedTrial(asdict(p))
            objective = cv_objective(spec, X, Y, SearchSpace(), cfg, base)
            t0 = time.perf_counter()
            score = objective(fixed)
            timing[batched] = (time.perf_counter() - t0, score)
        rows.append(
            {
                "params": asdict(p),
                "epochs": fixed.user_attrs["epochs"],
                "n_weights": fixed.user_attrs["n_weights"],
                "batched_s": timing[True][0],
                "sequential_s": timing[False][0],
                "ratio": timing[False][0] / timing[True][0],
                "cv_batched": timing[True][1],
                "cv_sequential": timing[False][1],
                "load": load(),
            }
        )
        print(json.dumps(rows[-1]), flush=True)
    total_b = sum(r["batched_s"] for r in rows)
    total_s = sum(r["sequential_s"] for r in rows)
    return {"trials": rows, "total_ratio": total_s / total_b}


def workers(data: str, trials: int) -> dict:
    """The same study (same trial parameters: the sampler is seeded by trial number) with
    ``--workers 1`` and ``--workers 2``, one thread each."""
    out = {}
    for n in (1, 2):
        with tempfile.TemporaryDirectory() as tmp:
            cmd = hpo(data, f"{tmp}/s.journal", "--trials", str(trials), "--workers", str(n))
            cmd += ["--threads", "1", "--out", f"{tmp}/m.safetensors"]
            t0 = time.perf_counter()
            done = subprocess.run(cmd, capture_output=True, text=True, check=True)
            wall = time.perf_counter() - t0
        report = json.loads(done.stdout)
        out[n] = {
            "wall_s": wall,
            "trials_per_hour": trials / wall * 3600,
            "complete": report["complete"],
            "pruned": report["pruned"],
            "load": load(),
        }
        print(n, json.dumps(out[n]), flush=True)
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("what", choices=("tiny", "folds", "workers"))
    parser.add_argument("--data", default="/tmp/hpo300.parquet")
    parser.add_argument("--trials", type=int, default=6)
    parser.add_argument("--stop-after", type=float, default=40.0, help="tiny: SIGTERM after S s")
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args()
    if not Path(args.data).exists():
        sim = ["sim", "dataset", "--scenario", "paper", "--n", "300", "--seed", "0"]
        subprocess.run([ROBOCAL, *sim, "--out", args.data], check=True)
    torch.set_num_threads(1)
    optuna.logging.set_verbosity(optuna.logging.WARNING)
    print(f"load average at start {load()}", flush=True)
    if args.what == "tiny":
        result = tiny(args.data, args.stop_after)
    elif args.what == "folds":
        result = folds(args.data, args.seed)
    else:
        result = workers(args.data, args.trials)
    print(json.dumps(result, indent=2, default=float))


if __name__ == "__main__":
    main()
