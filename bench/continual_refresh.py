"""Continual learning on a stream in recorded order, with and without a fresh network trained
on the memory as the stream grows (``ContinualConfig.refresh_growth``, :mod:`learner.refresh`),
against a batch model of the same training split: test mean (mm), 90 % coverage, wall time.
``--arms`` adds random arms of ``sim_sources.unseen`` (2,000 points, a random geometric error
of 20 noise floors and one hidden effect of 8, as ``learner_unseen.py`` takes them in turn).

    .venv/bin/python bench/continual_refresh.py --data /tmp/b.parquet /tmp/a.parquet \
        --seeds 0 1 2 [--growths 0 2] [--batch] [--arms 501 502 503 504]

``robocal continual --data D --refresh-growth G --json`` runs one cell of the table.
"""

import argparse
import json
import tempfile
import time
from pathlib import Path

import numpy as np
import torch
from learner_unseen import arm_spec

from kinematics.dataset import read_dataset
from learner.config import ContinualConfig
from learner.workflow import continual_on_dataset, train_on_dataset
from sim_sources.unseen import write_unseen


def stream(path: str, growth: float, seed: int) -> dict:
    """One dataset's training split streamed in recorded order at the defaults but ``growth``."""
    start = time.perf_counter()
    cfg = ContinualConfig(refresh_growth=growth, seed=seed)
    result = continual_on_dataset(read_dataset(path), cfg, seed=seed)
    return {
        "mean_mm": result.test.mean_mm,
        "coverage_90": result.test.coverage_90,
        "wall_s": time.perf_counter() - start,
    }


def batch(path: str, seed: int) -> dict:
    """``robocal train``'s model of the same split (its defaults, ``--base best``)."""
    start = time.perf_counter()
    result = train_on_dataset(read_dataset(path), seed=seed)
    return {
        "mean_mm": result.test.mean_mm,
        "coverage_90": result.test.coverage_90,
        "wall_s": time.perf_counter() - start,
    }


def arm_campaign(seed: int, folder: Path) -> tuple[str, str]:
    """Random arm ``seed``'s campaign of 2,000 points, written into ``folder``: its path and a
    label naming its hidden effect."""
    spec = arm_spec(seed, 2000)
    return str(write_unseen(spec, folder / f"arm{seed}")[0]), f"arm {seed} ({spec.hidden})"


def compared(
    path: str, label: str, growths: list[float], seeds: list[int], with_batch: bool
) -> list[dict]:
    """One dataset's rows, named ``label``: each growth, and the batch model, averaged over
    ``seeds``."""
    names = [f"refresh {g:g}" for g in growths] + (["batch"] if with_batch else [])
    rows = []
    for name, growth in zip(names, [*growths, None], strict=False):
        if growth is None:
            per_seed = [batch(path, s) for s in seeds]
        else:
            per_seed = [stream(path, growth, s) for s in seeds]
        row = {"data": label, "model": name, "seeds": seeds}
        for key in ("mean_mm", "coverage_90", "wall_s"):
            row[key] = float(np.mean([r[key] for r in per_seed]))
        row["per_seed_mm"] = [round(r["mean_mm"], 4) for r in per_seed]
        rows.append(row)
        print(json.dumps(row), flush=True)
    return rows


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--data", nargs="*", default=[])
    ap.add_argument("--arms", nargs="*", type=int, default=[], help="random arms' seeds")
    ap.add_argument("--seeds", nargs="+", type=int, default=[0])
    ap.add_argument("--growths", nargs="+", type=float, default=[0.0, 2.0])
    ap.add_argument("--batch", action="store_true", help="also the batch model of each split")
    args = ap.parse_args()
    torch.set_num_threads(1)
    rows: list[dict] = []
    with tempfile.TemporaryDirectory() as tmp:
        cases = [(path, path) for path in args.data]
        cases += [arm_campaign(seed, Path(tmp)) for seed in args.arms]
        for path, label in cases:
            rows += compared(path, label, args.growths, args.seeds, args.batch)
    print("| data | model | mean mm (per seed) | 90 % coverage | wall s |")
    print("|---|---|---|---|---|")
    for r in rows:
        seeds = " / ".join(f"{m:.3f}" for m in r["per_seed_mm"])
        print(
            f"| {r['data']} | {r['model']} | {r['mean_mm']:.3f} ({seeds}) | "
            f"{100 * r['coverage_90']:.1f} % | {r['wall_s']:.0f} |"
        )


if __name__ == "__main__":
    main()
