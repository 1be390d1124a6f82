"""Forward kinematics + pose error throughput on one core.

Measures poses per second for the pinocchio model (``RobotModel.fk``, one C++ call per pose
from Python) and for the vectorised numpy ``kinematics.effects.dh_poses`` (one batch), each
followed by ``pose_error`` against a fixed measured pose set, for both shipped robots.

    taskset -c 0 .venv/bin/python bench/kinematics_fk.py
"""

from __future__ import annotations

import argparse
import os
import time

os.environ.setdefault("OMP_NUM_THREADS", "1")
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import numpy as np  # noqa: E402

from kinematics.description import load_description  # noqa: E402
from kinematics.effects import dh_poses, dh_table  # noqa: E402
from kinematics.model import RobotModel  # noqa: E402
from kinematics.transforms import pose_error  # noqa: E402


def best_rate(fn, n_poses: int, repeats: int) -> float:
    """Poses per second of the fastest of ``repeats`` runs of ``fn``."""
    best = np.inf
    for _ in range(repeats):
        t0 = time.perf_counter()
        fn()
        best = min(best, time.perf_counter() - t0)
    return n_poses / best


def rates_for(robot: str, n: int, repeats: int) -> tuple[float, dict[str, float]]:
    """The max FK disagreement (m) of the two paths and their rates (poses/s) for ``robot``."""
    desc = load_description(robot)
    model = RobotModel(desc)
    lim = desc.limits_rad
    q = np.random.default_rng(0).uniform(lim[:, 0], lim[:, 1], (n, desc.n_joints))
    measured = model.fk(q)
    table = dh_table(desc)

    def numpy_fk() -> np.ndarray:
        return dh_poses(desc.to_dh(q), table) @ desc.tool[None]

    check = float(np.abs(numpy_fk() - measured).max())
    return check, {
        "pinocchio fk": best_rate(lambda: model.fk(q), n, repeats),
        "pinocchio fk + pose_error": best_rate(
            lambda: pose_error(measured, model.fk(q)), n, repeats
        ),
        "numpy dh_poses": best_rate(numpy_fk, n, repeats),
        "numpy dh_poses + pose_error": best_rate(
            lambda: pose_error(measured, numpy_fk()), n, repeats
        ),
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--n", type=int, default=20_000, help="poses per run")
    parser.add_argument("--repeats", type=int, default=7)
    args = parser.parse_args()
    if hasattr(os, "sched_getaffinity"):
        print(f"cores available to this process: {len(os.sched_getaffinity(0))}")
    print(f"load average at start: {os.getloadavg()[0]:.2f}; best of {args.repeats} runs")
    for robot in ("ur10", "fanuc_m900ib700"):
        check, rates = rates_for(robot, args.n, args.repeats)
        print(f"{robot}: N = {args.n}, max |dh_poses - pinocchio| = {check:.1e} m")
        for name, rate in rates.items():
            print(f"  {name:30s} {rate:12,.0f} poses/s")


if __name__ == "__main__":
    main()
