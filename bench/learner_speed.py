"""Learner speed on this machine: single-pose and 1,000-pose prediction latency, the ensemble
module (``module_*``: batched heads, head by head when evaluating 256+ rows) against one
``nn.Sequential`` per head (train step and inference), and one
continual pass over the paper campaign's 2,704 training points (N_m=500, n_B=100).

    .venv/bin/python bench/learner_speed.py [--data /tmp/paper.parquet]
"""

import argparse
import json
import os
import time

import numpy as np
import torch
from torch import nn

from kinematics.dataset import read_dataset
from kinematics.description import load_description
from learner.config import ContinualConfig, ModelConfig, TrainConfig
from learner.continual import ContinualLearner
from learner.encoding import n_inputs
from learner.evidential import evidential_elements
from learner.features import feature_spec
from learner.model import ErrorModel
from learner.workflow import prepare


def timed(fn, repeats):
    fn()
    times = []
    for _ in range(repeats):
        t = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t)
    return np.array(times)


def separate_models(n_in, cfg: ModelConfig):
    def mlp():
        layers, width = [], n_in
        for _ in range(cfg.hidden_layers):
            layers += [nn.Linear(width, cfg.neurons), nn.GELU()]
            width = cfg.neurons
        return nn.Sequential(*layers, nn.Linear(width, 4))

    return nn.ModuleList([mlp() for _ in range(6 * cfg.members)])


def separate_forward(models, x):
    outs = torch.stack([m(x) for m in models], dim=1)  # (N, heads, 4)
    sp = nn.functional.softplus
    return outs[..., 0], sp(outs[..., 1]), sp(outs[..., 2]) + 1, sp(outs[..., 3])


def continual_pass(path: str) -> float:
    """Wall time (s) of initialise + every update over the training split in order."""
    p = prepare(read_dataset(path), test_fraction=0.1, seed=0)
    train = np.sort(p.train)
    model = ErrorModel.create(p.spec, ModelConfig(), TrainConfig(), 0, p.robot)
    learner = ContinualLearner(model, ContinualConfig(memory=500, batch=100))
    start = time.perf_counter()
    for _ in learner.learn_stream(p.X[train], p.Y[train]):
        pass
    return time.perf_counter() - start


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--data", default="/tmp/paper.parquet")
    args = ap.parse_args()
    torch.set_num_threads(1)
    desc = load_description("fanuc_m900ib700")
    spec = feature_spec(desc, 15, True)
    cfg = ModelConfig()
    model = ErrorModel.create(spec, cfg, TrainConfig(), 0, desc.name)
    rng = np.random.default_rng(0)
    X = rng.uniform(spec.low, spec.high, (1000, spec.n_features))
    one = timed(lambda: model.predict(X[:1]), 2000)
    thousand = timed(lambda: model.predict(X), 200)
    out = {
        "model": f"{cfg.hidden_layers}x{cfg.neurons} {cfg.activation}, {model.n_weights} weights",
        "predict_1_p50_ms": 1e3 * np.percentile(one, 50),
        "predict_1_p99_ms": 1e3 * np.percentile(one, 99),
        "predict_1000_p50_ms": 1e3 * np.percentile(thousand, 50),
        "predict_1000_p99_ms": 1e3 * np.percentile(thousand, 99),
    }
    net = model.net
    width = n_inputs(spec, cfg.encoding)
    seq = separate_models(width, cfg)
    xb = torch.randn(64, width)
    yb = torch.randn(64, 6 * cfg.members)
    for name, params, fwd in (
        ("module", net.parameters(), net),
        ("separate", seq.parameters(), lambda x: separate_forward(seq, x)),
    ):
        opt = torch.optim.Adam(list(params), lr=1e-3, foreach=True)

        def step(fwd=fwd, opt=opt, train=model.train_cfg):
            opt.zero_grad()
            evidential_elements(yb, *fwd(xb), train.lam, train.nll_variance_power).mean().backward()
            opt.step()

        out[f"{name}_train_step_bs64_ms"] = 1e3 * np.median(timed(step, 500))
        xin = model.scale_x(X)
        with torch.inference_mode():
            out[f"{name}_infer_1000_ms"] = 1e3 * np.median(
                timed(lambda fwd=fwd, x=xin: fwd(x), 200)
            )
            x1 = xin[:1]
            out[f"{name}_infer_1_ms"] = 1e3 * np.median(timed(lambda fwd=fwd, x=x1: fwd(x), 2000))
    for key in ("train_step_bs64_ms", "infer_1000_ms", "infer_1_ms"):
        out[f"speedup_{key}"] = out[f"separate_{key}"] / out[f"module_{key}"]
    if os.path.exists(args.data):
        out["continual_pass_2704_s"] = continual_pass(args.data)
    out["load_average_1min_at_end"] = os.getloadavg()[0]
    print(
        json.dumps(
            {k: (round(v, 4) if isinstance(v, float) else v) for k, v in out.items()}, indent=1
        )
    )


if __name__ == "__main__":
    main()
