"""Learner accuracy on the real UR10 laser-tracker data (ur10-ipa Series A and B): a 90/10
held-out split of Series A, and cross-series (trained on A's training split, tested on all of
B), against the uncalibrated error after frames identification (the importer's T_W_0, T_6_S).

    .venv/bin/robocal import ipa ../shared/data/ur10-ipa/Series_A --out /tmp/a.parquet
    .venv/bin/robocal import ipa ../shared/data/ur10-ipa/Series_B --out /tmp/b.parquet
    .venv/bin/python bench/learner_ur10.py --a /tmp/a.parquet --b /tmp/b.parquet
"""

import argparse
import json
import time

import torch

from kinematics.dataset import read_dataset
from learner.config import ModelConfig, TrainConfig
from learner.metrics import accuracy_report
from learner.model import ErrorModel
from learner.workflow import prepare


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--a", default="/tmp/a.parquet")
    ap.add_argument("--b", default="/tmp/b.parquet")
    ap.add_argument("--max-epochs", type=int, default=300)
    args = ap.parse_args()
    torch.set_num_threads(1)
    a = prepare(read_dataset(args.a), test_fraction=0.1, seed=0)
    b = prepare(read_dataset(args.b), test_fraction=0.0, seed=0, spec=a.spec)
    model = ErrorModel.create(
        a.spec, ModelConfig(), TrainConfig(max_epochs=args.max_epochs), 0, a.robot
    )
    start = time.perf_counter()
    rep = model.fit(a.X[a.train], a.Y[a.train])
    out = {
        "features": list(a.spec.names),
        "n_train": len(a.train),
        "epochs": rep.epochs,
        "train_s": time.perf_counter() - start,
        "held_out_A": accuracy_report(model, a.X[a.test], a.Y[a.test]).to_dict(),
        "cross_A_to_B": accuracy_report(model, b.X, b.Y).to_dict(),
    }
    print(json.dumps(out, indent=1))


if __name__ == "__main__":
    main()
