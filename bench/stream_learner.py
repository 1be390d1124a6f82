"""Learner stage update time per batch (features + labels + ContinualLearner.update + metrics
+ snapshot), for the paper's reference setting (N_m=500, n_B=100) and the demo's learner, which
is the production example's (deploy/robocal.example.toml, N_m=4000; an update over more than
2,000 memory points trains proportionally fewer epochs).

    .venv/bin/python bench/stream_learner.py [--n 900]
"""

from __future__ import annotations

import argparse
import time
from dataclasses import replace

import numpy as np
import torch

from kinematics.description import load_description
from learner.config import ContinualConfig
from sim_sources.cell import simulate
from sim_sources.scenarios import get_scenario
from stream.demo import DEMO_LEARNER
from stream.learner_core import LearnerCore
from stream.points import dataset_to_points
from wire import Batch


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--n", type=int, default=900, help="points streamed in batches of 100")
    args = parser.parse_args()
    torch.set_num_threads(1)
    ds = simulate(get_scenario("paper"), args.n, 0)
    points = dataset_to_points(ds)
    batches = [
        Batch(seq=i, points=tuple(points[i * 100 : i * 100 + 100])) for i in range(args.n // 100)
    ]
    reference = replace(DEMO_LEARNER, continual=ContinualConfig(memory=500))
    for label, cfg in (
        ("paper (N_m=500)", reference),
        ("demo = production (N_m=4000)", DEMO_LEARNER),
    ):
        core = LearnerCore(load_description(ds.meta.robot), cfg, np.asarray(ds.meta.T_W_0))
        times, last = [], None
        for b in batches:
            start = time.perf_counter()
            update = core.add_batch(b)
            if update is not None and update.metrics.model_version > 1:
                times.append(time.perf_counter() - start)
                last = update.metrics
        t = np.array(times)
        print(
            f"{label:30s}: {len(t)} updates after the first model, per batch mean "
            f"{t.mean():.2f} s, min {t.min():.2f} s, max {t.max():.2f} s; final memory "
            f"{last.memory_size}, held-out mean error {last.test_mean_mm:.3f} mm"
        )


if __name__ == "__main__":
    main()
