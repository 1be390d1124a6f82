"""Compensation near singular poses: each policy's outcome on the demo's 50 held-out commands.

    .venv/bin/python bench/compensation_policy.py                      # trains the model (~2 min)
    .venv/bin/python bench/compensation_policy.py --model m.safetensors --save m.safetensors

The sim ``paper`` campaign of ``make demo`` (3004 points, seed 0); every tenth point is held
out (as the demo's learner does) and a batch model (``robocal train`` defaults) is trained on
the rest. The first 50 held-out commands (the demo's) are compensated through
:func:`stream.compensation_guard.guarded_compensate` with each policy and the corrected
commands are scored on the simulator's true robot (position error against the nominal pose
the command asked for). "Landed": the solver residual is within the guard's
``max_residual_m``; refused / flagged: the reply's policy with ``trusted: false``; the
orientation residual is what a command gives up of the target orientation (best effort lands
the position first).
"""

from __future__ import annotations

import argparse
import time
from dataclasses import replace

import numpy as np
import torch

from kinematics.model import RobotModel
from kinematics.transforms import pose_error
from learner.config import DEFAULT_BASE
from learner.snapshot import load_snapshot, save_snapshot
from learner.workflow import train_on_dataset
from sim_sources.cell import SimulatedCell, simulate
from sim_sources.scenarios import get_scenario
from stream.compensation import CompensationConfig, CompensationRequest
from stream.compensation_guard import GuardConfig, guarded_compensate

N, SEED, N_COMMANDS = 3004, 0, 50


def run_policy(model, robot, ds, rows, cfg: CompensationConfig, guard: GuardConfig) -> tuple:
    """The replies to the held-out commands ``rows`` and the seconds they took."""
    temps = [c for c in ds.table if c.startswith("temp_")]
    q, defl = ds.q(), ds.deflection()
    replies, start = [], time.perf_counter()
    for i in rows:
        req = CompensationRequest(
            q=tuple(q[i]),
            temperatures={c[5:]: float(ds.table[c].iloc[i]) for c in temps},
            deflection=tuple(defl[i]),
        )
        replies.append(guarded_compensate(model, robot, req, cfg, 0, guard))
    return replies, time.perf_counter() - start


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--model", default=None, help="reuse a model trained by this bench")
    parser.add_argument("--save", default=None, help="save the trained model here")
    parser.add_argument(
        "--limits",
        type=float,
        nargs="+",
        default=[0.02, 0.05, 0.5],
        help="best-effort joint-motion limits, rad",
    )
    args = parser.parse_args()
    torch.set_num_threads(1)
    ds = simulate(get_scenario("paper"), N, SEED)
    held = np.arange(9, N, 10)
    rows = held[:N_COMMANDS]
    if args.model:
        model = load_snapshot(args.model)
    else:
        t0 = time.perf_counter()
        train = np.setdiff1d(np.arange(N), held)
        model = train_on_dataset(
            ds.subset(train), test_fraction=0.0, seed=SEED, base=DEFAULT_BASE
        ).model
        print(f"trained on {len(train)} points in {time.perf_counter() - t0:.0f} s", flush=True)
        if args.save:
            save_snapshot(model, args.save)
    robot = RobotModel(model.spec.description)
    sim = SimulatedCell(get_scenario("paper"), N, SEED)
    cond = sim.conditions(rows)
    target = RobotModel(sim.model.description).fk(cond.q)

    def true_error_mm(q: np.ndarray) -> np.ndarray:
        poses = sim.truth.poses(replace(cond, q=q))
        return 1e3 * np.linalg.norm(pose_error(poses, target)[:, :3], axis=1)

    guard = GuardConfig()
    before = true_error_mm(cond.q)
    print(
        f"{len(rows)} held-out commands, true position error before {before.mean():.3f} mm; "
        f"landed = solver residual <= {guard.max_residual_m * 1e3:.3f} mm"
    )
    header = (
        "| policy | landed | refused | flagged | max residual mm | policy answers: max joint "
        "motion rad, max orientation residual arcmin | true error after, mean / landed mean / "
        "max mm | s |"
    )
    print(header + "\n|---|---|---|---|---|---|---|---|")
    setups = [("refuse", None), ("flag", None)] + [("best_effort", lim) for lim in args.limits]
    for policy, limit in setups:
        cfg = CompensationConfig(policy=policy)
        if limit is not None:
            cfg = replace(cfg, joint_motion_limit_rad=limit)
        replies, seconds = run_policy(model, robot, ds, rows, cfg, guard)
        residual = np.array([r.residual_m for r in replies]) * 1e3
        applied = [r for r in replies if r.policy != "none"]
        motion = max((r.joint_motion_rad for r in applied), default=0.0)
        arcmin = max((np.degrees(r.residual_rad) * 60.0 for r in applied), default=0.0)
        landed = residual <= guard.max_residual_m * 1e3
        refused = sum(r.policy == "refuse" and not r.trusted for r in replies)
        flagged = sum(r.policy in ("flag", "best_effort") and not r.trusted for r in replies)
        after = true_error_mm(np.array([r.q_corrected for r in replies]))
        name = policy if limit is None else f"{policy} ({limit:g} rad)"
        print(
            f"| {name} | {landed.sum()} | {refused} | {flagged} | {residual.max():.3f} "
            f"| {motion:.3f}, {arcmin:.2f} | {after.mean():.3f} / "
            f"{after[landed].mean():.3f} / {after.max():.3f} | {seconds:.1f} |",
            flush=True,
        )
        for r, m in zip(replies, after, strict=True):
            if r.policy != "none":
                print(
                    f"    {r.policy}: {r.reason or 'landed'}; {r.residual_m * 1e3:.4f} mm, "
                    f"{np.degrees(r.residual_rad) * 60:.2f} arcmin, {r.joint_motion_rad:.3f} rad"
                    f"; true error {m:.3f} mm",
                    flush=True,
                )


if __name__ == "__main__":
    main()
