"""Honest intervals under shift, on the stream: prequential 90 % coverage (each new point scored
by the published model before it is learned) when the stream moves somewhere the model has
not been, with the adaptive conformal interval scale (``aci_rate`` 0.05, the default) and
without it (0).

- Paper campaign: continual learning on the q1 < 0 half, then the q1 >= 0 half streams in.
- UR10: a model batch-trained on Series A goes on (``continual --from``) through Series B.

    .venv/bin/python bench/learner_shift.py --paper /tmp/paper.parquet \
        --a /tmp/a.parquet --b /tmp/b.parquet
"""

import argparse
import json
import tempfile
from pathlib import Path

import numpy as np
import torch

from kinematics.dataset import read_dataset
from learner.config import DEFAULT_BASE, ContinualConfig, ModelConfig, TrainConfig
from learner.continual import ContinualLearner, load_learner
from learner.model import ErrorModel
from learner.workflow import prepare, train_on_dataset
from stream.reports.learner import write_trained


def prequential(learner: ContinualLearner, X: np.ndarray, Y: np.ndarray, batch: int) -> dict:
    """Coverage of the position components of each batch before it is learned."""
    inside, first = [], None
    for i in range(0, len(X), batch):
        lo, hi = learner.model.predict(X[i : i + batch]).interval(0.9)
        y = Y[i : i + batch]
        inside.append(((y >= lo) & (y <= hi))[:, :3])
        learner.update(X[i : i + batch], y)
        if first is None and sum(len(b) for b in inside) >= 300:
            first = float(np.concatenate(inside).mean())
    every = np.concatenate(inside)
    per_batch = [round(float(b.mean()), 3) for b in inside]
    return {"coverage_90": float(every.mean()), "first_300": first, "per_batch": per_batch}


def paper(path: str, rate: float) -> dict:
    p = prepare(read_dataset(path), test_fraction=0.1, seed=0)
    train = np.sort(p.train)
    left, right = train[p.X[train, 0] < 0], train[p.X[train, 0] >= 0]
    model = ErrorModel.create(p.spec, ModelConfig(), TrainConfig(), 0, p.robot)
    learner = ContinualLearner(model, ContinualConfig(memory=500, batch=100, aci_rate=rate))
    for _ in learner.learn_stream(p.X[left], p.Y[left]):
        pass
    return prequential(learner, p.X[right], p.Y[right], 100)


def ur10(a: str, b: str, rate: float, folder: Path) -> dict:
    model_path = folder / "a.safetensors"
    if not model_path.exists():
        result = train_on_dataset(
            read_dataset(a), train_cfg=TrainConfig(max_epochs=300), base=DEFAULT_BASE
        )
        write_trained(result, model_path)
    learner = load_learner(model_path, ContinualConfig(aci_rate=rate))
    p = prepare(read_dataset(b), test_fraction=0.0, spec=learner.model.spec)
    X, Y = p.X, p.Y
    learner.carry(X[:50], Y[:50])
    return prequential(learner, X, Y, 50)


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--paper", default="/tmp/paper.parquet")
    ap.add_argument("--a", default="/tmp/a.parquet")
    ap.add_argument("--b", default="/tmp/b.parquet")
    args = ap.parse_args()
    torch.set_num_threads(1)
    out = {}
    with tempfile.TemporaryDirectory() as tmp:
        for rate in (0.05, 0.0):
            out[f"paper_other_half_aci_{rate}"] = paper(args.paper, rate)
            out[f"ur10_A_to_B_aci_{rate}"] = ur10(args.a, args.b, rate, Path(tmp))
            print(json.dumps({k: v for k, v in out.items() if k.endswith(str(rate))}), flush=True)
    print(json.dumps(out, indent=1))


if __name__ == "__main__":
    main()
