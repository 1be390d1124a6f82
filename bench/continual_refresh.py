"""Continual learning on a stream in recorded order, with and without a fresh network trained
on the memory as the stream grows (``ContinualConfig.refresh_growth``, :mod:`learner.refresh`),
against a batch model of the same training split: test mean (mm), 90 % coverage, wall time.

    .venv/bin/python bench/continual_refresh.py --data /tmp/b.parquet /tmp/a.parquet \
        --seeds 0 1 2 [--growths 0 2] [--batch]

``robocal continual --data D --refresh-growth G --json`` runs one cell of the table.
"""

import argparse
import json
import time

import numpy as np
import torch

from kinematics.dataset import read_dataset
from learner.config import ContinualConfig
from learner.workflow import continual_on_dataset, train_on_dataset


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


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--data", nargs="+", required=True)
    ap.add_argument("--seeds", nargs="+", type=int, default=[0])
    ap.add_argument("--growths", nargs="+", type=float, default=[0.0, 2.0])
    ap.add_argument("--batch", action="store_true", help="also the batch model of each split")
    args = ap.parse_args()
    torch.set_num_threads(1)
    rows = []
    for path in args.data:
        names = [f"refresh {g:g}" for g in args.growths] + (["batch"] if args.batch else [])
        for name, growth in zip(names, [*args.growths, None], strict=False):
            if growth is None:
                per_seed = [batch(path, s) for s in args.seeds]
            else:
                per_seed = [stream(path, growth, s) for s in args.seeds]
            row = {"data": path, "model": name, "seeds": args.seeds}
            for key in ("mean_mm", "coverage_90", "wall_s"):
                row[key] = float(np.mean([r[key] for r in per_seed]))
            row["per_seed_mm"] = [round(r["mean_mm"], 4) for r in per_seed]
            rows.append(row)
            print(json.dumps(row), flush=True)
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
