"""Learner accuracy on the simulated paper campaign (90/10 split): batch, continual max-error
replay (N_m=500, n_B=100), naive fine-tuning, interval coverage and the epistemic ratio.

    .venv/bin/python bench/learner_paper.py [--data /tmp/paper.parquet] [--model '{"members": 1}']

``--model`` overrides ModelConfig fields (JSON) for every model of the run. ``--base`` is the
physics base (default geometric: batch models identify it on their training points, continual
ones from their first points, ``auto``; ``nominal`` is the learner alone).
"""

import argparse
import json
import time
from pathlib import Path

import numpy as np
import torch

from kinematics.dataset import read_dataset
from learner.base import make_base
from learner.config import DEFAULT_BASE, ContinualConfig, ModelConfig, TrainConfig
from learner.continual import ContinualLearner
from learner.metrics import accuracy_report
from learner.model import ErrorModel
from learner.workflow import prepare
from sim_sources import get_scenario, write_campaign


def continual(p, strategy, train, model_cfg, base):
    model = ErrorModel.create(p.spec, model_cfg, TrainConfig(), 0, p.robot)
    kind = "nominal" if base == "nominal" else "auto"
    cfg = ContinualConfig(memory=500, batch=100, strategy=strategy, base=kind)
    learner = ContinualLearner(model, cfg)
    start = time.perf_counter()
    early = None
    for m in learner.learn_stream(p.X[train], p.Y[train]):
        if early is None and m.n_seen >= 550:  # the first 550 points seen
            early_model_err = accuracy_report(learner.model, p.X[train[:550]], p.Y[train[:550]])
            early = early_model_err.mean_mm
    wall = time.perf_counter() - start
    rep = accuracy_report(learner.model, p.X[p.test], p.Y[p.test])
    first = accuracy_report(learner.model, p.X[train[:550]], p.Y[train[:550]])
    return rep, wall, early, first.mean_mm


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--data", default="/tmp/paper.parquet")
    ap.add_argument("--model", default="{}", help="ModelConfig overrides as JSON")
    ap.add_argument("--base", default=DEFAULT_BASE, choices=("nominal", "geometric"))
    args = ap.parse_args()
    model_cfg = ModelConfig(**json.loads(args.model))
    torch.set_num_threads(1)
    if not Path(args.data).exists():  # the reference campaign, as `robocal sim dataset` writes it
        write_campaign(get_scenario("paper"), 3004, 0, args.data)
    ds = read_dataset(args.data)
    p = prepare(ds, test_fraction=0.1, seed=0)
    out = {
        "model_config": model_cfg.__dict__,
        "base": args.base,
        "noise_floor_mm": 1e3 * ds.meta.noise_floor_m,
        "uncalibrated_test_mean_mm": float(np.linalg.norm(p.Y[p.test, :3], axis=1).mean() * 1e3),
    }
    start = time.perf_counter()
    base = make_base(args.base, p.spec, p.X[p.train], p.Y[p.train])
    batch = ErrorModel.create(p.spec, model_cfg, TrainConfig(), 0, p.robot, base)
    rep = batch.fit(p.X[p.train], p.Y[p.train])
    out["batch"] = accuracy_report(batch, p.X[p.test], p.Y[p.test]).to_dict()
    out["batch"] |= {
        "train_s": time.perf_counter() - start,
        "epochs": rep.epochs,
        "n_weights": batch.n_weights,
    }
    print(json.dumps({"batch": out["batch"]}), flush=True)
    train = np.sort(p.train)
    for strategy in ("max_error", "naive"):
        r, wall, early, first = continual(p, strategy, train, model_cfg, args.base)
        out[strategy] = r.to_dict() | {
            "wall_s": wall,
            "first550_after_550_mm": early,
            "first550_at_end_mm": first,
        }
        print(json.dumps({strategy: out[strategy]}), flush=True)
    # Epistemic: train on q1 < 0, compare the other half with held-out points of this half.
    q1 = p.X[:, 0]
    left = np.flatnonzero(q1 < 0)
    rng = np.random.default_rng(0)
    rng.shuffle(left)
    held, fit_idx = left[:200], left[200:]
    right = np.flatnonzero(q1 >= 0)
    half_base = make_base(args.base, p.spec, p.X[fit_idx], p.Y[fit_idx])
    half = ErrorModel.create(p.spec, model_cfg, TrainConfig(), 0, p.robot, half_base)
    half.fit(p.X[fit_idx], p.Y[fit_idx])
    # Per point: the epistemic variance of the position, summed over x, y, z (m²).
    var_in = half.predict(p.X[held]).epistemic()[:, :3].sum(axis=1)
    var_out = half.predict(p.X[right]).epistemic()[:, :3].sum(axis=1)
    ep_in, ep_out = var_in.mean(), var_out.mean()
    rep_in = accuracy_report(half, p.X[held], p.Y[held])
    rep_out = accuracy_report(half, p.X[right], p.Y[right])
    out["epistemic"] = {
        "in_mean_var": float(ep_in),
        "out_mean_var": float(ep_out),
        "ratio_var": float(ep_out / ep_in),
        "ratio_std": float(np.sqrt(ep_out / ep_in)),
        "median_ratio_var": float(np.median(var_out) / np.median(var_in)),
        "other_above_trained_p90": float(np.mean(var_out > np.percentile(var_in, 90))),
        "trained_half_mean_mm": rep_in.mean_mm,
        "other_half_mean_mm": rep_out.mean_mm,
        "trained_half_coverage_90": rep_in.coverage_90,
        "other_half_coverage_90": rep_out.coverage_90,
        "n_train": len(fit_idx),
        "n_held": len(held),
        "n_other": len(right),
    }
    print(json.dumps({"epistemic": out["epistemic"]}), flush=True)
    print(json.dumps(out, indent=1))


if __name__ == "__main__":
    main()
