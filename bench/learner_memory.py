"""How much the replay memory costs: continual max-error replay (n_B=100) at several memory
sizes N_m against reservoir replay, full retraining, a batch model trained on N_m random
points and one trained on every training point (``batch``, the base identified on them), on
the simulated paper campaign (90/10 split). Seeds vary the weights, the hold-out draw and the
random subset; every row runs the same seeds. Continual models identify their base from their
first points and again from their memory (:mod:`learner.continual_base`). With ``batch`` among
the baselines each max-error row is also compared with it seed by seed: the mean's excess over
batch and its paired 95 % Student-t interval (single seeds differ by up to ±11 %, so three
cannot place a 5 % target).

    .venv/bin/python bench/learner_memory.py [--data /tmp/paper.parquet] [--seeds 3]
        [--first-seed 0] [--memories 200,500,1000,2000] [--baselines reservoir,full,random,batch]
"""

import argparse
import json
import time

import numpy as np
import torch
from scipy import stats

from kinematics.dataset import read_dataset
from learner.base import make_base
from learner.config import ContinualConfig, ModelConfig, TrainConfig
from learner.continual import ContinualLearner
from learner.metrics import accuracy_report
from learner.model import ErrorModel
from learner.workflow import prepare


def continual(p, train, strategy: str, memory: int, seed: int) -> dict:
    model = ErrorModel.create(p.spec, ModelConfig(), TrainConfig(seed=seed), seed, p.robot)
    cfg = ContinualConfig(memory=memory, batch=100, strategy=strategy, seed=seed)
    learner = ContinualLearner(model, cfg)
    start = time.perf_counter()
    for _ in learner.learn_stream(p.X[train], p.Y[train]):
        pass
    rep = accuracy_report(learner.model, p.X[p.test], p.Y[p.test])
    return {
        "mean_mm": rep.mean_mm,
        "coverage_90": rep.coverage_90,
        "wall_s": time.perf_counter() - start,
    }


def batch_subset(p, n: int, seed: int) -> dict:
    subset = np.random.default_rng(seed).choice(p.train, n, replace=False)
    model = ErrorModel.create(p.spec, ModelConfig(), TrainConfig(seed=seed), seed, p.robot)
    model.fit(p.X[subset], p.Y[subset])
    rep = accuracy_report(model, p.X[p.test], p.Y[p.test])
    return {"mean_mm": rep.mean_mm, "coverage_90": rep.coverage_90}


def batch_all(p, seed: int) -> dict:
    train = np.sort(p.train)
    base = make_base("geometric", p.spec, p.X[train], p.Y[train])
    model = ErrorModel.create(p.spec, ModelConfig(), TrainConfig(seed=seed), seed, p.robot, base)
    start = time.perf_counter()
    model.fit(p.X[p.train], p.Y[p.train])
    rep = accuracy_report(model, p.X[p.test], p.Y[p.test])
    return {
        "mean_mm": rep.mean_mm,
        "coverage_90": rep.coverage_90,
        "wall_s": time.perf_counter() - start,
    }


def one_run(p, train, strategy: str, memory: int, seed: int) -> dict:
    if strategy == "batch on random":
        return batch_subset(p, memory, seed)
    if strategy == "batch":
        return batch_all(p, seed)
    return continual(p, train, strategy, memory, seed)


def against_batch(continual: np.ndarray, batch: np.ndarray) -> dict:
    """Continual against batch over the same seeds (test mean mm each): the excess of the mean
    and the paired 95 % t-interval of the per-seed difference, both as a share of batch's mean."""
    diff, scale = continual - batch, float(batch.mean())
    row = {"vs_batch": float(continual.mean()) / scale - 1.0}
    if len(diff) > 1:
        low, high = stats.t.interval(0.95, len(diff) - 1, diff.mean(), stats.sem(diff))
        row["paired_95"] = [float(low) / scale, float(high) / scale]
    return row


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--data", default="/tmp/paper.parquet")
    ap.add_argument("--seeds", type=int, default=3, help="how many seeds, from --first-seed")
    ap.add_argument("--first-seed", type=int, default=0)
    ap.add_argument("--memories", default="200,500,1000,2000")
    ap.add_argument("--baselines", default="reservoir,full,random,batch")
    args = ap.parse_args()
    torch.set_num_threads(1)
    p = prepare(read_dataset(args.data), test_fraction=0.1, seed=0)
    train = np.sort(p.train)  # recording order
    runs = [("max_error", int(m)) for m in args.memories.split(",") if m]
    baselines = {
        "reservoir": ("reservoir", 500),
        "full": ("full", len(train)),
        "random": ("batch on random", 500),
        "batch": ("batch", len(train)),
    }
    runs += [baselines[b] for b in args.baselines.split(",") if b]
    seeds = range(args.first_seed, args.first_seed + args.seeds)
    per_seed = {}
    for strategy, memory in runs:
        results = [one_run(p, train, strategy, memory, seed) for seed in seeds]
        means = [r["mean_mm"] for r in results]
        per_seed[strategy, memory] = np.array(means)
        row = {
            "strategy": strategy,
            "memory": memory,
            "mean_mm": float(np.mean(means)),
            "per_seed_mm": [round(m, 4) for m in means],
            "coverage_90": float(np.mean([r["coverage_90"] for r in results])),
        }
        if "wall_s" in results[0]:
            row["wall_s"] = float(np.mean([r["wall_s"] for r in results]))
        print(json.dumps(row), flush=True)
    if ("batch", len(train)) in per_seed:
        batch = per_seed["batch", len(train)]
        for (strategy, memory), means in per_seed.items():
            if strategy == "max_error":
                row = {"against_batch": memory} | against_batch(means, batch)
                print(json.dumps(row), flush=True)


if __name__ == "__main__":
    main()
