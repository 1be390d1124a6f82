"""No poisoning (issue 19): a campaign streamed through the continual learner clean and with a
tracker offset burst, the published model's held-out error compared, quarantine counted.

A burst is ``--burst-len`` consecutive streamed points whose measured position (the tracker
frame's ``x, y, z``) is moved by ``--burst-mm`` in a seeded random direction, starting at a
seeded point between 25 % and 75 % of the stream; the labels are recomputed from the bumped
table, as the learner stage would compute them. Test points (a seeded 10 %) stay clean: they
are the truth the published model is measured against. Per seed: a clean run and one run per
burst size with the quarantine on; for the first seed also the clean and poisoned runs with
the quarantine and gate off (what the defence changes; ``--no-off`` skips them). TP = burst
points quarantined, FP = other points quarantined, withheld = updates the gate kept back.

The clean and the poisoned run of a seed share their random numbers batch by batch (common
random numbers): before each batch the learner's generator, which draws the batch's held-out
share, is re-seeded from (seed, batch index). With one generator for the whole stream, the 30
quarantined points shortened one batch's draw and every later batch drew another held-out
set, so the two runs differed in every batch after the burst, not only in it (the larger part
of their difference is another: BENCHMARKS.md). Training is single-threaded and its shuffling
seeded per fit, so a run is reproducible to the last digit. ``--ideal`` streams the clean
stream without the burst rows: what the learner is given when the quarantine catches exactly
the burst.

    .venv/bin/robocal sim dataset --scenario paper --n 3004 --seed 0 --out /tmp/paper.parquet
    .venv/bin/robocal import ipa /work/shared/data/ur10-ipa/Series_A --out /tmp/a.parquet
    .venv/bin/python bench/poisoning.py --data /tmp/paper.parquet --seeds 0 1 2 --burst-mm 20 50
    .venv/bin/python bench/poisoning.py --data /tmp/a.parquet --rows 3000 --base nominal

``--rows`` streams only the first rows in time order (the split is drawn among them);
``--memory``, ``--batch``, ``--init`` and ``--base`` are the continual configuration;
``--gate-only`` runs the poisoned streams with the publish gate alone (quarantine off);
``--clean-only`` runs the clean pair (quarantine off / on) alone, e.g. on a scenario with a
genuine drift (``--scenario``-generated datasets ``thermal_expansion``, ``tracker_drift``).
"""

import argparse
import json
import math
import time
from dataclasses import replace

import numpy as np
import torch

from kinematics.dataset import Dataset, read_dataset
from learner.config import ContinualConfig, ModelConfig, QuarantineConfig, TrainConfig
from learner.continual import ContinualLearner
from learner.model import ErrorModel
from learner.workflow import prepare

OFF = QuarantineConfig(enabled=False, publish_tolerance=math.inf)


def bumped(ds: Dataset, rows: np.ndarray, mm: float, rng: np.random.Generator) -> Dataset:
    """``ds`` with the measured position of ``rows`` moved by ``mm`` in a random direction."""
    direction = rng.normal(size=3)
    direction /= np.linalg.norm(direction)
    table = ds.table.copy()
    cols = [table.columns.get_loc(c) for c in ("x", "y", "z")]
    table.iloc[rows, cols] = table.iloc[rows, cols].to_numpy() + 1e-3 * mm * direction
    return Dataset(table, ds.meta)


def run(
    ds: Dataset, cfg: ContinualConfig, seed: int, burst: np.ndarray, drop: bool = False
) -> dict:
    """Stream the training rows of ``ds`` in time order (without the ``burst`` rows when
    ``drop``); the published model's test error (mm) at the end and after each step, and the
    counts of points the quarantine kept out."""
    p = prepare(ds, test_fraction=0.1, seed=0)
    stream = np.sort(p.train)
    given = ~np.isin(stream, burst) if drop else np.ones(len(stream), dtype=bool)
    X, Y = p.X[stream], p.Y[stream]
    model = ErrorModel.create(p.spec, ModelConfig(), TrainConfig(seed=seed), seed, p.robot)
    learner = ContinualLearner(model, replace(cfg, seed=seed))
    out = np.zeros(len(X), dtype=bool)
    start = time.perf_counter()
    steps = [(0, cfg.init)] + [(i, i + cfg.batch) for i in range(cfg.init, len(X), cfg.batch)]
    curve = []
    for k, (a, b) in enumerate(steps):
        learner.rng = np.random.default_rng([seed, k])  # common random numbers (module doc)
        Xk, Yk = X[a:b][given[a:b]], Y[a:b][given[a:b]]
        ok = learner.screen(Xk, Yk)
        out[np.flatnonzero(given[a:b]) + a] = ~ok
        if k == 0:
            learner.initialize(Xk[ok], Yk[ok], screened=True)
        else:
            learner.update(Xk[ok], Yk[ok], screened=True)
        curve.append(test_mm(learner.model, p.X[p.test], p.Y[p.test]))
    is_burst = np.isin(stream, burst)
    first = int(np.argmax(is_burst)) if is_burst.any() else len(X)
    return {
        "test_mean_mm": curve[-1],
        "burst_step": next((k for k, (a, b) in enumerate(steps) if first < b), len(steps)),
        "curve": [round(c, 6) for c in curve],
        "tp": int((out & is_burst).sum()),
        "fp": int((out & ~is_burst).sum()),
        "withheld": learner.n_withheld,
        "released": learner.quarantine.released,
        "version": learner.version,
        "n_stream": len(X),
        "wall_s": round(time.perf_counter() - start, 1),
    }


def test_mm(model: ErrorModel, X: np.ndarray, Y: np.ndarray) -> float:
    """Mean position error (mm) of ``model`` on the test points."""
    return float(np.linalg.norm((model.predict(X).gamma - Y)[:, :3], axis=1).mean() * 1e3)


def burst_rows(ds: Dataset, length: int, rng: np.random.Generator) -> np.ndarray:
    """``length`` consecutive streamed (training) rows from a point in 25-75 % of the stream."""
    p = prepare(ds, test_fraction=0.1, seed=0)
    stream = np.sort(p.train)
    k = int(rng.integers(len(stream) // 4, 3 * len(stream) // 4 - length))
    return stream[k : k + length]


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--data", default="/tmp/paper.parquet")
    ap.add_argument("--rows", type=int, default=None, help="stream only the first rows")
    ap.add_argument("--seeds", nargs="+", type=int, default=[0, 1, 2])
    ap.add_argument("--burst-mm", nargs="+", type=float, default=[20.0, 50.0])
    ap.add_argument("--burst-len", type=int, default=30)
    ap.add_argument("--memory", type=int, default=500)
    ap.add_argument("--batch", type=int, default=100)
    ap.add_argument("--init", type=int, default=50)
    ap.add_argument("--base", default="auto", choices=("auto", "nominal"))
    ap.add_argument("--clean-only", action="store_true")
    ap.add_argument("--no-off", action="store_true", help="skip the runs without the defence")
    ap.add_argument(
        "--gate-only", action="store_true", help="only poisoned runs with the gate, no quarantine"
    )
    ap.add_argument(
        "--ideal",
        action="store_true",
        help="also the clean stream without the burst rows (what a perfect quarantine leaves)",
    )
    args = ap.parse_args()
    torch.set_num_threads(1)
    ds = read_dataset(args.data)
    if args.rows:
        ds = Dataset(ds.table.iloc[: args.rows].reset_index(drop=True), ds.meta)
    on = ContinualConfig(memory=args.memory, batch=args.batch, init=args.init, base=args.base)
    off = replace(on, quarantine=OFF)
    none = np.empty(0, dtype=int)
    rows = []

    def record(seed: int, mm: float, defence: str, r: dict) -> None:
        rows.append({"seed": seed, "burst_mm": mm, "defence": defence, **r})
        print(json.dumps(rows[-1]), flush=True)

    gate = replace(on, quarantine=QuarantineConfig(enabled=False))
    for i, seed in enumerate(args.seeds):
        if args.gate_only:
            for mm in args.burst_mm:
                rng = np.random.default_rng([seed, int(mm)])
                burst = burst_rows(ds, args.burst_len, rng)
                record(seed, mm, "gate", run(bumped(ds, burst, mm, rng), gate, seed, burst))
            continue
        with_off = i == 0 and not args.no_off
        if with_off:
            record(seed, 0.0, "off", run(ds, off, seed, none))
        record(seed, 0.0, "on", run(ds, on, seed, none))
        if args.clean_only:
            continue
        for mm in args.burst_mm:
            rng = np.random.default_rng([seed, int(mm)])
            burst = burst_rows(ds, args.burst_len, rng)
            poisoned = bumped(ds, burst, mm, rng)
            record(seed, mm, "on", run(poisoned, on, seed, burst))
            if args.ideal:
                record(seed, mm, "ideal", run(ds, on, seed, burst, drop=True))
            if with_off:
                record(seed, mm, "off", run(poisoned, off, seed, burst))
    clean = {(r["seed"], r["defence"]): r for r in rows if r["burst_mm"] == 0}
    for r in rows:
        ref = clean.get((r["seed"], r["defence"]), clean.get((r["seed"], "on")))
        r["vs_clean"] = None if ref is None else r["test_mean_mm"] / ref["test_mean_mm"] - 1.0
        k = r["burst_step"]  # the published models from the burst's batch on, averaged
        after = None if ref is None else np.mean(r["curve"][k:]) / np.mean(ref["curve"][k:]) - 1
        r["vs_clean_after"] = None if after is None or r["burst_mm"] == 0 else float(after)
    print(json.dumps({"data": args.data, "args": vars(args), "runs": rows}, indent=1))


if __name__ == "__main__":
    main()
