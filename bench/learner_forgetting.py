"""Forgetting on the simulated paper campaign: the training split is streamed region by region
(q1 < 0 first, then q1 >= 0; N_m=500, n_B=100); the error on held-out region-one points is
measured when region one is done and at the end, for max-error replay and naive fine-tuning.

    .venv/bin/python bench/learner_forgetting.py [--data /tmp/paper.parquet]
"""

import argparse
import json

import numpy as np
import torch

from kinematics.dataset import read_dataset
from learner.config import ContinualConfig, ModelConfig, TrainConfig
from learner.continual import ContinualLearner
from learner.metrics import accuracy_report
from learner.model import ErrorModel
from learner.workflow import prepare


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--data", default="/tmp/paper.parquet")
    args = ap.parse_args()
    torch.set_num_threads(1)
    p = prepare(read_dataset(args.data), test_fraction=0.1, seed=0)
    q1 = p.X[:, 0]
    train = np.sort(p.train)
    order = np.concatenate([train[q1[train] < 0], train[q1[train] >= 0]])
    n_one = int(np.sum(q1[train] < 0))
    test_one = p.test[q1[p.test] < 0]
    out = {"n_region_one": n_one, "n_region_two": len(order) - n_one, "n_test_one": len(test_one)}
    for strategy in ("max_error", "naive"):
        model = ErrorModel.create(p.spec, ModelConfig(), TrainConfig(), 0, p.robot)
        learner = ContinualLearner(model, ContinualConfig(memory=500, batch=100, strategy=strategy))
        after_one = None
        for m in learner.learn_stream(p.X[order], p.Y[order]):
            if after_one is None and m.n_seen >= n_one:
                after_one = accuracy_report(learner.model, p.X[test_one], p.Y[test_one]).mean_mm
        end = accuracy_report(learner.model, p.X[test_one], p.Y[test_one]).mean_mm
        out[strategy] = {
            "region_one_after_region_one_mm": after_one,
            "region_one_at_end_mm": end,
            "growth_pct": 100 * (end / after_one - 1),
        }
        print(json.dumps({strategy: out[strategy]}), flush=True)
    print(json.dumps(out, indent=1))


if __name__ == "__main__":
    main()
