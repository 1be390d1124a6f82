"""A model carried into a new day: trained on one UR10 series (physics base + residual, its
training split), then continued on the other series as ``robocal continual --from`` does. For k = 0,
10, 25, 50, 100 of the new series' first points in recorded order (as a new day starts: Series A's
first 100 span 40-130 deg per joint, B's nearly its whole range), ``ContinualLearner.carry``: the
base's frames (``T_W_0``, tool) re-identified from those k points (MAP, the network's residual taken
off) and the carried network's gain fitted on them; one update on them (k = 0: the model as it
answers before any of the day's points, ``learner.carry.before_day``), and the new series' held-out
test error (10 %, seed 0, drawn over the whole series) with 90 % coverage and how much wider the
epistemic spread is there than on the source's own test points, and the share of test points the
compensation service would flag as untrusted (epistemic std above its limit, or a joint or
thermometer past the angles or temperatures the model was trained on, ``learner.envelope``: both
shares; or all of them while the model is ``unverified``: a carry that took the frames as moved, or
whose first points needed intervals ``learner.carry.MISS_EVIDENCE`` times wider than it starts with,
the model's scale times the ``drift_scale`` its training measured) with the 90 % coverage on the
trusted ones. Both directions, ``--seeds`` seeds. ``--cache DIR`` keeps the trained source models
(by series, base, seed and epochs) for the next run. ``--base-a`` / ``--base-b`` are the source
models' bases (a kind or a model file, e.g. ``robocal gap``'s), ``--frame-prior-mm`` /
``--moved-frame-prior-mm`` the carry's frame priors (equal: no choice; ``ContinualConfig``),
``--new-setup`` carries as ``continual --new-setup`` does (the tracker's frame free, not with
``--days``), ``--reference-program`` as ``continual --reference-program`` (the geometry fitted on
the k points too);
``frames_moved`` is the share of seeds whose carry took the frames as moved. ``--order spread``
draws the k points at random from the whole new series instead (seeded; spread over its time
too, which no day's start is); ``--order reference`` takes them in
:func:`kinematics.reference.reference_order` from among its first ``--window`` training points
(``robocal data reference-poses``): a day that starts with a reference program, measured in its
first hours. ``--target-frames carry`` (the default) gives the new
series its tracker frame ``T_W_0`` as identified from the carry's own k points
(:func:`kinematics.frames.reframed`; k = 0 keeps the importer's), which is all a new day knows
when it starts; ``series`` keeps the importer's, fitted on every row of the series, its test
points included (the figures recorded before 2026-12-06 were measured so). ``--days FILE``
carries within one series instead: its points up to its first pause of more than ``--gap-h``
hours (recorded order; UR10 Series A: its first 5,252 points, 18 h, then a 6.5 h pause) and the
rest, both ways: another day of the same cell, the tracker not set up anew, so the new day is
in the frames the model's own day gave (each day's fitted on its own points).

``--whole-day N`` streams the new series' first ``N`` training points after the carry instead (in
``--order``; ``--init``, the carry's points): the carry on its first ``init`` points
(``ContinualConfig``), then one update per ``batch`` of them from the first, as ``robocal continual
--from`` does. After each update: the test mean, the 90 % coverage, the untrusted share and the
coverage of the trusted answers; the coverage of the update's own batch, scored before it was
learned (prequential), with the share of it compensation would have trusted then and their coverage
(what a line asking then got); and the coverage of the test points the stream has already passed in
recorded order and of those still ahead of it, the latter also with the intervals as wide as a day
the model has not seen gets (``learner.carry.before_day``: times its ``drift_scale``).


    .venv/bin/python bench/learner_transfer.py --a /tmp/a.parquet --b /tmp/b.parquet --seeds 0 1 2
    .venv/bin/python bench/learner_transfer.py --days /tmp/a.parquet --seeds 0 1 2
    .venv/bin/python bench/learner_transfer.py --seeds 0 --whole-day 1800
"""

import argparse
import json
import tempfile
import time
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np
import torch

from kinematics.dataset import Dataset, read_dataset, write_dataset
from kinematics.frames import reframed
from kinematics.reference import program_first
from learner.carry import before_day
from learner.config import (
    DEFAULT_BASE,
    FRAME_PRIOR_MM,
    MOVED_FRAME_PRIOR_MM,
    ContinualConfig,
    TrainConfig,
)
from learner.continual import load_learner
from learner.metrics import accuracy_report, trust
from learner.model import ErrorModel
from learner.workflow import nominal_description, prepare, train_on_dataset
from stream.compensation import CompensationConfig
from stream.reports.learner import write_trained

#: What the compensation service flags as untrusted (epistemic std of a position component).
EPISTEMIC_LIMIT_MM = CompensationConfig().epistemic_limit_mm

STEPS = (0, 10, 25, 50, 100)

#: ``--order reference`` picks its points from the new series' first this many training points:
#: UR10 Series A's first 1,101 rows (3.0 h), B's first 1,095 of 1,495 (its timestamps are lost).
REFERENCE_WINDOW = 1000


@dataclass(frozen=True)
class Carry:
    """One carry the bench measures: ``source``'s model (trained on ``base`` for ``epochs``
    with ``seed``, cached in ``folder``) carried to ``target`` under the continual settings
    ``continual`` (its seed the run's), on the new series' points in ``order``
    (:func:`stream_order`), in the data frames ``target_frames`` names (:func:`in_frames`)."""

    source: str
    target: str
    seed: int
    epochs: int
    folder: Path
    base: str
    continual: ContinualConfig
    target_frames: str = "carry"
    order: str = "recorded"
    window: int = REFERENCE_WINDOW


def source_model(run: Carry) -> tuple[Path, ErrorModel, float]:
    """The model of ``run.source`` (trained on its ``base``, ``epochs``, ``seed``), cached in
    its ``folder``: its file, the model and its test mean (mm)."""
    source, seed, epochs, folder, base = run.source, run.seed, run.epochs, run.folder, run.base
    tag = "" if base == DEFAULT_BASE else f"_{Path(base).parent.name}_{Path(base).stem}"
    model_path = folder / f"{Path(source).stem}{tag}_seed{seed}_e{epochs}.safetensors"
    if model_path.is_file():
        model = load_learner(model_path, ContinualConfig(seed=seed)).model
        return model_path, model, model.metrics["mean_mm"]
    result = train_on_dataset(
        read_dataset(source),
        seed=seed,
        train_cfg=TrainConfig(max_epochs=epochs, seed=seed),
        base=base,
    )
    write_trained(result, model_path)
    return model_path, result.model, result.test.mean_mm


def in_frames(frames: str, source: str, target: Dataset, rows: np.ndarray) -> Dataset:
    """The new series ``target`` in the data frames (``T_W_0``, ``T_6_S``) of ``frames``: those
    the carry's points ``rows`` give (``carry``: all a new day knows when it starts), its
    importer's, fitted on every row, test points included (``series``), or the source
    series' (``source``: the same tracker set-up, the frames kept from the day before)."""
    if frames == "carry":
        return reframed(target, nominal_description(target), rows)
    if frames == "source":
        src = read_dataset(source).meta
        return Dataset(target.table, replace(target.meta, T_W_0=src.T_W_0, T_6_S=src.T_6_S))
    return target


def stream_order(run: Carry, target: Dataset, train: np.ndarray) -> np.ndarray:
    """The new series' training rows ``train`` in the order the carry meets them: as recorded,
    ``spread`` (shuffled over the whole series, seeded), or ``reference``: the first
    ``max(STEPS)`` in :func:`kinematics.reference.reference_order` from among its first
    ``run.window`` training points (a reference program measured when the day starts), then
    the rest as recorded."""
    recorded = np.sort(train)
    if run.order == "spread":
        return np.random.default_rng(run.seed).permutation(train)
    if run.order == "reference":
        desc = nominal_description(target)
        return program_first(desc, target.q(), recorded, max(STEPS), run.window)
    return recorded


def transfer(run: Carry) -> dict:
    """One carry (:class:`Carry`), measured after k = :data:`STEPS` of the new series' points."""
    model_path, model, source_mm = source_model(run)
    cfg = replace(run.continual, seed=run.seed)
    p_src = prepare(read_dataset(run.source), test_fraction=0.1, seed=run.seed, spec=model.spec)
    epi_src = np.sqrt(model.predict(p_src.X[p_src.test]).epistemic()[:, :3]).mean()
    target_ds = read_dataset(run.target)
    p = prepare(target_ds, test_fraction=0.1, seed=0, spec=model.spec)
    stream = stream_order(run, target_ds, p.train)
    if run.target_frames == "source":  # the same at every k
        ds_src = in_frames("source", run.source, target_ds, stream)
        p = prepare(ds_src, test_fraction=0.1, seed=0, spec=model.spec)
    rows = []
    for k in STEPS:
        if k and run.target_frames == "carry":  # k = 0 keeps the importer's, prepared above
            ds_k = in_frames("carry", run.source, target_ds, stream[:k])
            p = prepare(ds_k, test_fraction=0.1, seed=0, spec=model.spec)
        X, Y, Xte, Yte = p.X[stream], p.Y[stream], p.X[p.test], p.Y[p.test]
        learner = load_learner(model_path, cfg)
        t0 = time.perf_counter()
        if k:
            gain = learner.carry(X[:k], Y[:k])
            frames_only = accuracy_report(learner.model, Xte, Yte).mean_mm
            learner.update(X[:k], Y[:k])
        else:
            frames_only, gain = float("nan"), 1.0
        model = learner.model if k else before_day(learner.model)
        frames_moved = float("frames moved" in learner.base.note)
        r = accuracy_report(model, Xte, Yte)
        ev = model.predict(Xte)
        epi_std = np.sqrt(ev.epistemic()[:, :3])
        epi = epi_std.mean()
        lo, hi = ev.interval(0.9)
        inside = (Yte[:, :3] >= lo[:, :3]) & (Yte[:, :3] <= hi[:, :3])
        flags = trust(model, Xte, EPISTEMIC_LIMIT_MM)
        untrusted = flags.untrusted
        rows.append(
            {
                "k": k,
                "frames_only_mm": frames_only,
                "residual_gain": gain,
                "frames_moved": frames_moved,
                "mean_mm": r.mean_mm,
                "p95_mm": r.p95_mm,
                "max_mm": r.max_mm,
                "coverage_90": r.coverage_90,
                "epistemic_ratio": float(epi / epi_src),
                "over_epistemic_limit_share": float(flags.over_epistemic_limit.mean()),
                "outside_envelope_share": float(flags.past_envelope.mean()),
                "untrusted_share": float(untrusted.mean()),
                "coverage_90_trusted": float(inside[~untrusted].mean())
                if (~untrusted).any()
                else float("nan"),
                "time_s": time.perf_counter() - t0,
            }
        )
    return {"source_test_mm": source_mm, "steps": rows}


def whole_day(run: Carry, n: int) -> list[dict]:
    """One carry (:class:`Carry`) streamed through the new series' first ``n`` training points
    in its order (:func:`stream_order`; ``--whole-day``; data frames ``carry``: the carry's
    ``init`` points): one row per update."""
    model_path, _, _ = source_model(run)
    cfg = replace(run.continual, seed=run.seed)
    learner = load_learner(model_path, cfg)
    ds = read_dataset(run.target)
    p = prepare(ds, test_fraction=0.1, seed=0, spec=learner.model.spec)
    order = stream_order(run, ds, p.train)
    if run.target_frames != "series":
        ds = in_frames(run.target_frames, run.source, ds, order[: cfg.init])
        p = prepare(ds, test_fraction=0.1, seed=0, spec=learner.model.spec)
    stream, test = order[:n], np.sort(p.test)
    X, Y, Xte, Yte = p.X[stream], p.Y[stream], p.X[test], p.Y[test]

    def covered(m: np.ndarray, model: ErrorModel | None = None) -> float:
        model = model or learner.model
        return accuracy_report(model, Xte[m], Yte[m]).coverage_90 if m.any() else np.nan

    learner.carry(X[: cfg.init], Y[: cfg.init])
    rows = []
    for i in range(0, len(X), cfg.batch):
        batch = slice(i, i + cfg.batch)
        Xb, Yb = X[batch], Y[batch]
        live = ~trust(learner.model, Xb, EPISTEMIC_LIMIT_MM).untrusted
        live_covered = (
            accuracy_report(learner.model, Xb[live], Yb[live]).coverage_90 if live.any() else np.nan
        )
        step = learner.update(Xb, Yb)
        untrusted = trust(learner.model, Xte, EPISTEMIC_LIMIT_MM).untrusted
        passed = test <= stream[min(i + cfg.batch, len(X)) - 1]
        rows.append(
            {
                "points": min(i + cfg.batch, len(X)),
                "mean_mm": accuracy_report(learner.model, Xte, Yte).mean_mm,
                "coverage_90": covered(np.ones(len(test), dtype=bool)),
                "untrusted_share": float(untrusted.mean()),
                "coverage_90_trusted": covered(~untrusted),
                "coverage_90_prequential": step.batch_coverage_90,
                "prequential_trusted_share": float(live.mean()),
                "coverage_90_prequential_trusted": live_covered,
                "coverage_90_passed": covered(passed),
                "coverage_90_ahead": covered(~passed),
                "coverage_90_ahead_drift_wide": covered(~passed, before_day(learner.model)),
            }
        )
    return rows


def split_days(path: str, folder: Path, gap_h: float) -> tuple[str, str]:
    """The series at ``path`` cut at its first pause of more than ``gap_h`` hours between two
    points in recorded order, written to ``folder``: the day before, and the days after, each
    in the frames its own points give."""
    ds = read_dataset(path)
    pauses = np.flatnonzero(np.diff(ds.table["t"].to_numpy(float)) > gap_h * 3600.0)
    if not pauses.size:
        raise SystemExit(f"{path}: no pause of more than {gap_h:g} h between two points")
    cut, stem = pauses[0] + 1, Path(path).stem
    parts = (np.arange(cut), np.arange(cut, len(ds)))
    paths = [folder / f"{stem}_{name}.parquet" for name in ("before", "after")]
    desc = nominal_description(ds)
    for rows, out in zip(parts, paths, strict=True):  # each day's frames from its own points
        write_dataset(reframed(ds, desc, rows).subset(rows), out)
    return str(paths[0]), str(paths[1])


def _mean(values: list[float]) -> float:
    """The mean over seeds of what they measured (NaN where none did: no frames-only error at
    k = 0, no trusted point left)."""
    v = np.asarray(values, dtype=float)
    return float(v[~np.isnan(v)].mean()) if (~np.isnan(v)).any() else float("nan")


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--a", default="/tmp/a.parquet")
    ap.add_argument("--b", default="/tmp/b.parquet")
    ap.add_argument("--seeds", nargs="+", type=int, default=[0, 1, 2])
    ap.add_argument("--max-epochs", type=int, default=300)
    ap.add_argument("--cache", help="folder keeping the trained source models between runs")
    ap.add_argument("--base-a", default=DEFAULT_BASE, help="A's base: a kind or a model file")
    ap.add_argument("--base-b", default=DEFAULT_BASE, help="B's base: a kind or a model file")
    ap.add_argument("--frame-prior-mm", type=float, default=FRAME_PRIOR_MM)
    ap.add_argument("--moved-frame-prior-mm", type=float, default=MOVED_FRAME_PRIOR_MM)
    ap.add_argument("--order", choices=("recorded", "spread", "reference"), default="recorded")
    ap.add_argument(
        "--window",
        type=int,
        default=REFERENCE_WINDOW,
        help="--order reference: choose among the new series' first N training points",
    )
    ap.add_argument(
        "--target-frames",
        choices=("carry", "series"),
        default="carry",
        help="the new series' T_W_0 from the carry's k points, or the importer's (every row)",
    )
    ap.add_argument("--new-setup", action="store_true", help="carry as a new tracker set-up")
    ap.add_argument(
        "--reference-program",
        action="store_true",
        help="carry as continual --reference-program does (with --order reference)",
    )
    ap.add_argument("--days", help="one series: carry its first day to the rest and back")
    ap.add_argument("--gap-h", type=float, default=4.0, help="--days: the pause that ends a day")
    ap.add_argument("--whole-day", type=int, help="stream this many of the new series' points")
    ap.add_argument("--init", type=int, help="--whole-day: the carry's points (ContinualConfig)")
    args = ap.parse_args()
    torch.set_num_threads(1)
    out = {}
    with tempfile.TemporaryDirectory() as tmp:
        folder = Path(args.cache or tmp)
        folder.mkdir(parents=True, exist_ok=True)
        continual = ContinualConfig(
            frame_prior_mm=args.frame_prior_mm,
            moved_frame_prior_mm=args.moved_frame_prior_mm,
            new_setup=args.new_setup and not args.days,
            reference_program=args.reference_program,
            init=args.init or ContinualConfig().init,
        )
        a, b = split_days(args.days, folder, args.gap_h) if args.days else (args.a, args.b)
        directions = {"A->B": (a, b, args.base_a), "B->A": (b, a, args.base_b)}
        # --days: one tracker set-up, so a day goes on in the frames the other one had
        target_frames = "source" if args.days else args.target_frames
        for name, (src, dst, base) in directions.items():
            runs = [
                Carry(
                    src,
                    dst,
                    s,
                    args.max_epochs,
                    folder,
                    base,
                    continual,
                    target_frames,
                    args.order,
                    args.window,
                )
                for s in args.seeds
            ]
            if args.whole_day:
                days = [whole_day(run, args.whole_day) for run in runs]
                out[name] = [
                    {key: _mean([d[i][key] for d in days]) for key in days[0][i]}
                    for i in range(len(days[0]))
                ]
                continue
            runs = [transfer(run) for run in runs]
            steps = [
                {key: _mean([r["steps"][i][key] for r in runs]) for key in runs[0]["steps"][i]}
                for i in range(len(STEPS))
            ]
            out[name] = {
                "source_test_mm": float(np.mean([r["source_test_mm"] for r in runs])),
                "steps": steps,
                "per_seed_mean_mm": [[round(s["mean_mm"], 4) for s in r["steps"]] for r in runs],
            }
    print(json.dumps(out, indent=1))


if __name__ == "__main__":
    main()
