"""A whole day streamed after the tracker moved: a model trained on one day goes on, as
``robocal continual --from`` and the daemon's ``start_from`` do, through all of the next day's
training points in recorded order, its frames fitted again as the day's points double
(``ContinualConfig.day_frame_points``, default) or left as the first 50 points fitted them
(``day_frame_points = 0``), and with or without a fresh network trained on the memory as
the day's points double (``day_refresh_growth``). Reported per case and setting: the day's
prequential mean error and 90 % coverage (each batch scored before it is learned: what the line
saw during the day) and the final model's mean, p95 and 90 % coverage on the day's held-out 10 %.

Cases: random arms of ``sim_sources.unseen`` (``--arms``; 1,200 points, a hidden effect of 8
noise floors by seed, geometric error of 20; day 1 the poses with q1 below its median
(``--day1 corner``: below its lowest :data:`CORNER` share, a source that saw one corner), day 2
the poses with q1 above its median, with the tracker moved by 2 mm / 2 mrad and the tool by
1 mm / 1 mrad, in the old frames; with ``--day2 new-setup`` in the frame of a tracker set up
anew, as the nominal model fits the day's first 50 training points: ``new_setup_day``; with
``--day2 reference`` a day that starts with a reference program of 100 poses, its frames from
them) and, with
``--a`` / ``--b``, the real UR10 from Series A to Series B (nothing moved; the importer's
registration differs per series). Source models: 300 epochs, geometric base (``--base gap``:
their day's gap model, whose effects a reference program keeps or drops, and the day's
held-out points weigh again), seed 0, cached in ``--cache``. Each row also names the effects
the day ended on.

    .venv/bin/python bench/learner_moved_day.py --a /tmp/a.parquet --b /tmp/b.parquet \
        [--settings defaults "no fresh network"]
"""

import argparse
import json
import tempfile
import time
from dataclasses import replace
from pathlib import Path

import numpy as np
import torch
from learner_unseen import arm_spec

from kinematics.dataset import Dataset, read_dataset, write_dataset
from kinematics.frames import reframed
from kinematics.reference import program_first
from kinematics.transforms import (
    transform_from_xyz_quat,
    transform_from_xyz_rpy,
    xyz_quat_from_transform,
)
from learner.config import DEFAULT_BASE, ContinualConfig, TrainConfig
from learner.continual import load_learner
from learner.continual_records import prequential
from learner.workflow import (
    continual_on_dataset,
    nominal_description,
    prepare,
    train_on_dataset,
)
from sim_sources.unseen import write_unseen
from stream.reports.learner import write_trained

#: Points of a random arm's campaign, split into its two days.
ARM_POINTS = 1200
TRACKER_MOVE = transform_from_xyz_rpy([2e-3, -1e-3, 0.5e-3], [0.0, 1e-3, 2e-3])
TOOL_MOVE = transform_from_xyz_rpy([0.0, 1e-3, 0.0], [1e-3, 0.0, 0.0])
#: ContinualConfig fields changed from its defaults, by setting.
SETTINGS = {
    "defaults": {},
    "first points' frames": {"day_frame_points": 0},
    "no fresh network": {"day_refresh_growth": 0.0},
    "new set-up": {"new_setup": True},
    "new set-up, init 100": {"new_setup": True, "init": 100},
    "reference program": {"new_setup": True, "reference_program": True, "init": 100},
}
#: ``--day2 reference``: the reference program's poses, chosen among the day's first this many
#: training points (``kinematics.reference.reference_order``).
REFERENCE_POSES, REFERENCE_WINDOW = 100, 400
#: Where ``--day2 new-setup`` puts the tracker: metres from the old one, turned.
NEW_SETUP = transform_from_xyz_rpy([2.5, -1.2, -0.8], [0.01, -0.02, 2.4])
#: ``--day1 corner``: day 1 is the poses with q1 in this lowest share of its range of poses.
CORNER = 0.3


def moved_days(seed: int, folder: Path, corner: bool = False) -> tuple[Path, Path]:
    """Arm ``seed``'s two days (written once into ``folder``): day 2 seen by a moved tracker;
    with ``corner`` day 1 is q1's lowest :data:`CORNER` share."""
    root = folder / f"arm{seed}{'_corner' if corner else ''}"
    day1, day2 = root / "day1.parquet", root / "day2.parquet"
    if day2.is_file():
        return day1, day2
    ds = read_dataset(write_unseen(arm_spec(seed, ARM_POINTS), root)[0])
    t, cut = ds.table, ds.table.q1.median()
    first = t.q1 < (t.q1.quantile(CORNER) if corner else cut)
    write_dataset(Dataset(t[first].reset_index(drop=True), ds.meta), day1)
    later = t[t.q1 >= cut].reset_index(drop=True)
    T = transform_from_xyz_quat(
        later[["x", "y", "z"]].to_numpy(), later[["qx", "qy", "qz", "qw"]].to_numpy()
    )
    xyz, quat = xyz_quat_from_transform(TRACKER_MOVE[None] @ T @ TOOL_MOVE[None])
    later[["x", "y", "z"]], later[["qx", "qy", "qz", "qw"]] = xyz, quat
    write_dataset(Dataset(later, ds.meta), day2)
    return day1, day2


def new_setup_day(day2: Path, init: int, reference: bool = False) -> Path:
    """``day2`` seen by a tracker set up anew (written once beside it): its poses in the new
    tracker's frame, whose ``T_W_0`` the day knows only as the nominal model's fit to its first
    ``init`` training points (:func:`kinematics.frames.reframed`), the points a carry starts on.
    With ``reference`` those are a reference program: the training rows' places are refilled so
    that the :data:`REFERENCE_POSES` poses :func:`~kinematics.reference.program_first` picks
    among the first :data:`REFERENCE_WINDOW` come first, the rest after them in recorded order
    (the test rows, drawn by place, stay the same)."""
    path = day2.with_name(f"{day2.stem}_setup{init}{'_reference' if reference else ''}.parquet")
    if path.is_file():
        return path
    ds = read_dataset(day2)
    t = ds.table.copy()
    T = NEW_SETUP[None] @ transform_from_xyz_quat(
        t[["x", "y", "z"]].to_numpy(), t[["qx", "qy", "qz", "qw"]].to_numpy()
    )
    t[["x", "y", "z"]], t[["qx", "qy", "qz", "qw"]] = xyz_quat_from_transform(T)
    seen = Dataset(t, replace(ds.meta, frame="tracker", T_W_0=NEW_SETUP.tolist()))
    train = np.sort(prepare(seen, test_fraction=0.1, seed=0).train)
    if reference:
        desc = nominal_description(seen)
        rows = np.arange(len(t))
        rows[train] = program_first(desc, seen.q(), train, REFERENCE_POSES, REFERENCE_WINDOW)
        seen = Dataset(t.iloc[rows].reset_index(drop=True), seen.meta)
    write_dataset(reframed(seen, nominal_description(seen), train[:init]), path)
    return path


def source_model(day: Path, folder: Path, epochs: int, base: str = DEFAULT_BASE) -> Path:
    """The model of ``day`` (``base`` + residual, seed 0), trained once into ``folder``."""
    tag = "" if base == DEFAULT_BASE else f"_{base}"
    path = folder / f"{day.parent.name}_{day.stem}{tag}_e{epochs}.safetensors"
    if not path.is_file():
        result = train_on_dataset(
            read_dataset(day), seed=0, train_cfg=TrainConfig(max_epochs=epochs), base=base
        )
        write_trained(result, path)
    return path


def stream_day(model_path: Path, day: Path, changed: dict) -> dict:
    """All of ``day`` streamed from the model at ``model_path`` (its state: the memory), at the
    defaults but the ``changed`` config fields."""
    cfg = ContinualConfig(**changed)
    start = time.perf_counter()
    r = continual_on_dataset(read_dataset(day), cfg, start=load_learner(model_path, cfg))
    live = prequential(r.updates)
    return {
        "prequential_mm": live["mean_mm"],
        "prequential_coverage_90": live["coverage_90"],
        "mean_mm": r.test.mean_mm,
        "p95_mm": r.test.p95_mm,
        "coverage_90": r.test.coverage_90,
        "frames_fitted_on": r.learner.day.fitted,
        "effects": [e.name for e in r.learner.base.effects],
        "updates": len(r.updates),
        "time_s": time.perf_counter() - start,
    }


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--arms", nargs="*", type=int, default=[401, 402, 403, 404, 405, 406])
    ap.add_argument("--a", help="UR10 Series A (robocal import ipa): A -> B with --b")
    ap.add_argument("--b")
    ap.add_argument("--max-epochs", type=int, default=300)
    ap.add_argument("--cache", help="folder keeping the days and source models between runs")
    ap.add_argument("--settings", nargs="+", choices=list(SETTINGS), default=list(SETTINGS))
    ap.add_argument("--base", default=DEFAULT_BASE, help="the source models' base: a kind")
    ap.add_argument(
        "--day2",
        choices=("moved", "new-setup", "reference"),
        default="moved",
        help="the arms' day 2 seen by the moved tracker in the old frames, or by one set up anew "
        "(reference: and starting with a reference program, its frames from the program's poses)",
    )
    ap.add_argument(
        "--day1",
        choices=("half", "corner"),
        default="half",
        help="the arms' day 1: q1 below its median, or in its lowest CORNER share",
    )
    args = ap.parse_args()
    torch.set_num_threads(1)
    with tempfile.TemporaryDirectory() as tmp:
        folder = Path(args.cache or tmp)
        folder.mkdir(parents=True, exist_ok=True)
        corner = args.day1 == "corner"
        cases = {
            f"arm {s} ({arm_spec(s, ARM_POINTS).hidden})": moved_days(s, folder, corner)
            for s in args.arms
        }
        if args.day2 != "moved":
            reference = args.day2 == "reference"
            init = REFERENCE_POSES if reference else ContinualConfig().init
            cases = {k: (d1, new_setup_day(d2, init, reference)) for k, (d1, d2) in cases.items()}
        if args.a and args.b:
            cases["UR10 A -> B"] = Path(args.a), Path(args.b)
        out = {}
        for name, (day1, day2) in cases.items():
            model = source_model(day1, folder, args.max_epochs, args.base)
            out[name] = {k: stream_day(model, day2, SETTINGS[k]) for k in args.settings}
            print(json.dumps({name: out[name]}), flush=True)
    print(
        "| case | setting | prequential mm | prequential 90 % cov. | final mean mm | p95 | "
        "90 % cov. | fitted on | effects at the end | s |"
    )
    print("|---|---|---|---|---|---|---|---|---|---|")
    for name, rows in out.items():
        for setting, r in rows.items():
            print(
                f"| {name} | {setting} | {r['prequential_mm']:.4f} | "
                f"{100 * r['prequential_coverage_90']:.1f} % | {r['mean_mm']:.4f} | "
                f"{r['p95_mm']:.3f} | {100 * r['coverage_90']:.1f} % | "
                f"{r['frames_fitted_on']} | {', '.join(r['effects']) or '-'} | "
                f"{r['time_s']:.0f} |"
            )


if __name__ == "__main__":
    main()
