"""Off the training distribution: how honest a batch model's intervals stay, and what the
compensation service trusts there.

Models trained on one half of q1's range (q1 below its median; 200 points of that half held out)
are tested on the held-out points and on the other half: the simulated paper campaign and random
arms of ``sim_sources.unseen`` (as ``bench/learner_unseen.py``: a geometric error and one more
effect each). Models trained on the cooler 60 % of the poses (by their warmest thermometer) are
tested on the warmer rest, by how far (K) its thermometers read past the trained ones: the
margin of ``learner.envelope.MARGIN_K``. UR10 models of one series (90/10 split, seed 0) are
tested on the other series' test points with nothing of that series learned (k = 0 of
``bench/learner_transfer.py``). For each: test mean, 90 % coverage of all points, the share
compensation marks untrusted (a joint past the angles trained on or a thermometer past the
temperatures, ``learner.envelope``; or an epistemic std over its limit) and the coverage and
mean of the points it trusts. Default model, geometric base, seed 0.


    .venv/bin/python bench/learner_envelope.py --paper /tmp/paper.parquet \
        --a /tmp/a.parquet --b /tmp/b.parquet --arms 8
"""

import argparse
import json
import tempfile
import time

import numpy as np
import torch

from kinematics.dataset import read_dataset
from learner.base import make_base
from learner.config import DEFAULT_BASE, ModelConfig, TrainConfig
from learner.features import temperature_readings
from learner.metrics import accuracy_report, trust
from learner.model import ErrorModel
from learner.workflow import Prepared, prepare
from sim_sources.unseen import UnseenSpec, write_unseen
from stream.compensation import CompensationConfig

#: The effects the random arms take in turn (as ``bench/learner_unseen.py``).
EFFECTS = ("joint_compliance", "gear_periodic", "thermal_expansion", "joint_coupling")
EPISTEMIC_LIMIT_MM = CompensationConfig().epistemic_limit_mm


def trust_report(model: ErrorModel, X: np.ndarray, Y: np.ndarray) -> dict:
    """Accuracy of all points and of those compensation would trust (mm, shares)."""
    everything = accuracy_report(model, X, Y)
    flags = trust(model, X, EPISTEMIC_LIMIT_MM)
    trusted = ~flags.untrusted
    out = {
        "n": len(X),
        "mean_mm": everything.mean_mm,
        "coverage_90": everything.coverage_90,
        "outside_envelope": float(flags.past_envelope.mean()),
        "over_epistemic_limit": float(flags.over_epistemic_limit.mean()),
        "untrusted": float(1.0 - trusted.mean()),
        "trusted_mean_mm": float("nan"),
        "trusted_coverage_90": float("nan"),
    }
    if trusted.any():
        kept = accuracy_report(model, X[trusted], Y[trusted])
        out |= {"trusted_mean_mm": kept.mean_mm, "trusted_coverage_90": kept.coverage_90}
    return out


def fitted(p: Prepared, train: np.ndarray, epochs: int | None) -> ErrorModel:
    """The default model on the geometric base of ``train``, seed 0."""
    base = make_base(DEFAULT_BASE, p.spec, p.X[train], p.Y[train])
    cfg = TrainConfig() if epochs is None else TrainConfig(max_epochs=epochs)
    model = ErrorModel.create(p.spec, ModelConfig(), cfg, 0, p.robot, base)
    model.fit(p.X[train], p.Y[train])
    return model


def halves(p: Prepared, epochs: int | None) -> dict:
    """Trained on q1 below its median, tested on 200 held-out points of that half and on the
    other half."""
    q1 = p.X[:, 0]
    low = np.flatnonzero(q1 < np.median(q1))
    np.random.default_rng(0).shuffle(low)
    held, train = low[:200], np.sort(low[200:])
    other = np.flatnonzero(q1 >= np.median(q1))
    model = fitted(p, train, epochs)
    return {
        "trained_half": trust_report(model, p.X[held], p.Y[held]),
        "other_half": trust_report(model, p.X[other], p.Y[other]),
    }


#: Kelvin past the warmest trained reading of any thermometer, the bins of :func:`warmer`.
KELVIN_BINS = ((0.0, 0.5), (0.5, 1.0), (1.0, 1.5), (1.5, 2.0), (2.0, 3.0), (3.0, 5.0), (5.0, 10.0))


def warmer(p: Prepared, epochs: int | None) -> dict:
    """Trained on the poses whose warmest thermometer is below its 60th percentile (200 of them
    held out); the rest by how far past the trained readings: points, mean mm, 90 % coverage."""
    temps = np.column_stack(list(temperature_readings(p.spec, p.X).values()))
    cool = np.flatnonzero(temps.max(axis=1) < np.quantile(temps.max(axis=1), 0.6))
    np.random.default_rng(0).shuffle(cool)
    held, train = cool[:200], np.sort(cool[200:])
    model = fitted(p, train, epochs)
    past = (temps - temps[train].max(axis=0)).max(axis=1)
    out = {"trained_half": trust_report(model, p.X[held], p.Y[held])}
    for lo, hi in KELVIN_BINS:
        sel = np.flatnonzero((past > lo) & (past <= hi))
        if len(sel):
            rep = accuracy_report(model, p.X[sel], p.Y[sel])
            out[f"{lo:g}-{hi:g} K"] = {
                "n": len(sel),
                "mean_mm": rep.mean_mm,
                "coverage_90": rep.coverage_90,
            }
    return out


def arm(seed: int, n_points: int) -> dict:
    spec = UnseenSpec(
        seed=seed,
        n_points=n_points,
        hidden=EFFECTS[seed % 4],
        magnitude=8.0,
        also=(("geometric", 20.0),),
    )
    with tempfile.TemporaryDirectory() as folder:
        path, _, truth = write_unseen(spec, folder)
        p = prepare(read_dataset(path), test_fraction=0.0, seed=0)
    out = {"effect": spec.hidden, "axes": truth["n_axes"]} | halves(p, epochs=300)
    if spec.hidden == "thermal_expansion":
        out["warmer"] = warmer(p, epochs=300)
    return out


def series(source: str, target: str) -> dict:
    """A model of ``source`` on its own test points and on ``target``'s."""
    p = prepare(read_dataset(source), test_fraction=0.1, seed=0)
    q = prepare(read_dataset(target), test_fraction=0.1, seed=0, spec=p.spec)
    model = fitted(p, np.sort(p.train), epochs=300)
    return {
        "own_test": trust_report(model, p.X[p.test], p.Y[p.test]),
        "other_series_test": trust_report(model, q.X[q.test], q.Y[q.test]),
    }


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--paper", default="/tmp/paper.parquet")
    ap.add_argument("--a", default="/tmp/a.parquet")
    ap.add_argument("--b", default="/tmp/b.parquet")
    ap.add_argument("--arms", type=int, default=8, help="random arms, seeds 0..N-1")
    ap.add_argument("--points", type=int, default=2000, help="points per random arm")
    args = ap.parse_args()
    torch.set_num_threads(1)
    out: dict = {}
    start = time.perf_counter()
    paper = prepare(read_dataset(args.paper), test_fraction=0.0, seed=0)
    out["paper"] = halves(paper, None) | {"warmer": warmer(paper, None)}
    print(json.dumps({"paper": out["paper"]}), flush=True)
    for seed in range(args.arms):
        out[f"arm{seed}"] = arm(seed, args.points)
        print(json.dumps({f"arm{seed}": out[f"arm{seed}"]}), flush=True)
    for name, source, target in (("A_on_B", args.a, args.b), ("B_on_A", args.b, args.a)):
        out[name] = series(source, target)
        print(json.dumps({name: out[name]}), flush=True)
    out["wall_s"] = time.perf_counter() - start
    print(json.dumps(out, indent=1))


if __name__ == "__main__":
    main()
