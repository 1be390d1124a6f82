"""A multi-day real series streamed through the learner stage's core (``LearnerCore``, the
daemon's learner) in recorded order, batches of ``n_B`` points, with and without new days: a
pause of more than ``new_day_after_h`` (here 4 h) between points carries the model into the
new day (``ContinualLearner.carry``), ``inf`` (the default) never does. For each day after
the first: the position error and coverage of its first ``--day-batches`` batches after the
first, each scored before it was learned by the model then published (what the line was
answered with: its error, its 90 % intervals, the share compensation would flag untrusted
and the coverage of the rest), and over the whole stream the same prequential figures and the
final model's error on a held-out 10 % (seed 0, drawn over the whole series, never streamed).
The day's very first batch is answered by the last day's model either way: nothing tells the
stage it is a new day before its points come.

    .venv/bin/python bench/stream_new_day.py --data /tmp/a.parquet --new-day-after-h 4 inf
"""

from __future__ import annotations

import argparse
import json
import time
from dataclasses import replace

import numpy as np
import torch

from kinematics.dataset import read_dataset
from kinematics.description import load_description
from learner.metrics import accuracy_report, trust
from stream.compensation import CompensationConfig
from stream.learner_core import LearnerCore, LearnerStageConfig
from stream.points import dataset_to_points
from wire import Batch

EPISTEMIC_LIMIT_MM = CompensationConfig().epistemic_limit_mm


def scored(model, X: np.ndarray, Y: np.ndarray) -> dict:
    """Position error (mm) and 90 % coverage of ``X, Y`` under ``model``, the share it flags
    untrusted and the coverage of the trusted rest (position components)."""
    ev = model.predict(X)
    lo, hi = ev.interval(0.9)
    inside = (Y[:, :3] >= lo[:, :3]) & (Y[:, :3] <= hi[:, :3])
    error_mm = 1e3 * np.linalg.norm(Y[:, :3] - ev.mean[:, :3], axis=1)
    untrusted = trust(model, X, EPISTEMIC_LIMIT_MM).untrusted
    return {"inside": inside, "untrusted": untrusted, "error_mm": error_mm}


def summary(rows: list[dict]) -> dict:
    """Mean error (mm), coverage, untrusted share and trusted coverage over the scored batches
    ``rows``."""
    if not rows:
        return {"points": 0}
    inside = np.concatenate([r["inside"] for r in rows])
    error_mm = np.concatenate([r["error_mm"] for r in rows])
    untrusted = np.concatenate([r["untrusted"] for r in rows])
    trusted = inside[~untrusted]
    return {
        "points": len(inside),
        "mean_mm": float(error_mm.mean()),
        "coverage_90": float(inside.mean()),
        "untrusted_share": float(untrusted.mean()),
        "coverage_90_trusted": float(trusted.mean()) if len(trusted) else float("nan"),
    }


def stream(
    path: str, new_day_after_h: float, batch: int, day_batches: int, seed: int, gap_h: float
) -> dict:
    """The series at ``path`` through one ``LearnerCore`` (defaults, ``new_day_after_h``);
    days are scored where a pause exceeds ``gap_h`` hours."""
    ds = read_dataset(path)
    points = dataset_to_points(ds)
    test = np.zeros(len(points), dtype=bool)
    test[np.random.default_rng(0).permutation(len(points))[: len(points) // 10]] = True
    cfg = LearnerStageConfig(seed=seed, new_day_after_h=new_day_after_h)
    cfg = replace(cfg, continual=replace(cfg.continual, seed=seed))
    core = LearnerCore(load_description(ds.meta.robot), cfg, np.asarray(ds.meta.T_W_0))
    kept = [p for p, t in zip(points, test, strict=True) if not t]
    held = Batch(seq=0, points=tuple(p for p, t in zip(points, test, strict=True) if t))
    batches = [
        Batch(seq=i, points=tuple(kept[s : s + batch]))
        for i, s in enumerate(range(0, len(kept), batch))
    ]
    whole, days, since_pause, n_days, prev_t = [], [], None, 0, np.inf
    t0 = time.perf_counter()
    for b in batches:
        X, Y = core.features(b)
        fitted = core.learner is not None and core.learner.model.is_fitted
        t = np.array([prev_t, *(p.t for p in b.points)])
        prev_t = t[-1]
        if (np.diff(t) > gap_h * 3600.0).any():  # the same days for either setting
            since_pause, n_days = 0, n_days + 1
        elif since_pause is not None:
            since_pause += 1
        if fitted:
            row = scored(core.learner.model, X, Y)
            whole.append(row)
            if since_pause is not None and 1 <= since_pause <= day_batches:
                days.append(row)
        core.add_batch(b)
    Xte, Yte = core.features(held)
    test_report = accuracy_report(core.learner.model, Xte, Yte)
    return {
        "new_day_after_h": new_day_after_h,
        "days_after_the_first": n_days,
        "days_first_batches": summary(days),
        "whole_stream": summary(whole),
        "test_mean_mm": test_report.mean_mm,
        "test_coverage_90": test_report.coverage_90,
        "time_s": time.perf_counter() - t0,
    }


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--data", required=True, help="a dataset (robocal import ipa ...)")
    ap.add_argument("--new-day-after-h", type=float, nargs="+", default=[4.0, float("inf")])
    ap.add_argument("--batch", type=int, default=100, help="n_B")
    ap.add_argument("--day-batches", type=int, default=5, help="batches scored per new day")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--gap-h", type=float, default=4.0, help="the pause that ends a scored day")
    args = ap.parse_args()
    torch.set_num_threads(1)
    out = [
        stream(args.data, h, args.batch, args.day_batches, args.seed, args.gap_h)
        for h in args.new_day_after_h
    ]
    print(json.dumps(out, indent=1))


if __name__ == "__main__":
    main()
