"""ISO 9283 pose characteristics of the simulated cube program, before and after compensation.

    .venv/bin/python bench/iso9283.py                              # trains the model (~2-3 min)
    .venv/bin/python bench/iso9283.py --model m.safetensors --out /tmp/iso9283

The sim ``iso9283`` scenario (the ``paper`` robot, 5 poses of its largest reachable cube,
``--cycles`` cycles, seed 0) is measured; the model is trained with ``robocal train``'s defaults
on a separate campaign of the same robot (``paper``, 3004 points, seed 1). Three columns per
pose: *before* (measured against the nominal pose), *after, predicted* (what ``robocal report
iso9283 --model`` reports: the measured error less the model's prediction at the command) and
*after, executed*: every visit's command is corrected by the compensation service's code
(:func:`stream.compensation_guard.guarded_compensate`, the visit's temperatures and secondary
encoder deflections as features, default policy) and the simulated true robot is measured at
the corrected commands (same seeds: same temperatures, robot and tracker noise), scored against
the nominal pose the original command asked for.
"""

from __future__ import annotations

import argparse
import time
from dataclasses import replace

import numpy as np
import torch

from kinematics.dataset import Dataset
from kinematics.model import RobotModel
from kinematics.transforms import xyz_quat_from_transform
from learner.config import DEFAULT_BASE
from learner.snapshot import load_snapshot, save_snapshot
from learner.workflow import train_on_dataset
from sim_sources.cell import SimulatedCell, simulate
from sim_sources.scenarios import get_scenario
from stream.compensation import CompensationConfig, CompensationRequest
from stream.compensation_guard import guarded_compensate
from stream.reports.iso9283 import iso9283_report, markdown, write_report


def executed(cube: Dataset, model, seed: int) -> tuple[Dataset, dict]:
    """``cube`` with its poses measured at the compensated commands (the commanded joints
    kept, so the report scores them against the original targets) and the replies' policies."""
    scenario = get_scenario("iso9283")
    cell = SimulatedCell(scenario, len(cube), seed)
    robot = RobotModel(model.spec.description)
    temps = [c for c in cube.table if c.startswith("temp_")]
    q, defl = cube.q(), cube.deflection()
    corrected, policies = [], {}
    for k in range(len(cube)):
        req = CompensationRequest(
            q=tuple(q[k]),
            temperatures={c[5:]: float(cube.table[c].iloc[k]) for c in temps},
            deflection=tuple(defl[k]),
        )
        reply = guarded_compensate(model, robot, req, CompensationConfig(), 0)
        corrected.append(reply.q_corrected)
        policies[reply.policy] = policies.get(reply.policy, 0) + 1
    qc = np.array(corrected)
    approach = scenario.program.approach_rad * cell.program.approach
    cell.program = replace(cell.program, q=qc, q_pre=qc - approach)
    xyz, quat = xyz_quat_from_transform(cell.measure().T_W_S)
    table = cube.table.copy()
    table[["x", "y", "z"]] = xyz
    table[["qx", "qy", "qz", "qw"]] = quat
    return Dataset(table, cube.meta), policies


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--cycles", type=int, default=30, help="cycles per pose (standard: 30)")
    parser.add_argument("--model", default=None, help="reuse a model trained by this bench")
    parser.add_argument("--save", default=None, help="save the trained model here")
    parser.add_argument("--out", default="/tmp/iso9283_bench", help="report folder")
    args = parser.parse_args()
    torch.set_num_threads(1)
    cube = simulate(get_scenario("iso9283"), 5 * args.cycles, 0)
    program = cube.meta.extra["program"]
    print(
        f"cube edge {program['cube_edge_m'] * 1e3:.0f} mm at "
        f"{np.round(np.asarray(program['cube_centre_m']) * 1e3).tolist()} mm, {args.cycles} cycles"
    )
    if args.model:
        model = load_snapshot(args.model)
    else:
        t0 = time.perf_counter()
        train = simulate(get_scenario("paper"), 3004, 1)
        result = train_on_dataset(train, test_fraction=0.1, seed=0, base=DEFAULT_BASE)
        model = result.model
        print(
            f"trained on paper seed 1 ({result.n_train} points) in "
            f"{time.perf_counter() - t0:.0f} s, held-out {result.test.mean_mm:.4f} mm"
        )
        if args.save:
            save_snapshot(model, args.save)
    report = iso9283_report(cube, model, data="sim iso9283 seed 0", model_path="paper seed 1")
    md, png = write_report(report, args.out)
    print(markdown(report, png.name) + f"\nwrote {md} and {png}\n")
    t0 = time.perf_counter()
    ran, policies = executed(cube, model, 0)
    after = {p.name: p.before for p in iso9283_report(ran, None, data="executed").poses}
    seconds = time.perf_counter() - t0
    print(f"executed compensation: {len(ran)} commands in {seconds:.1f} s, policies {policies}")
    print(
        "| pose | AP_P mm before / after predicted / after executed | RP_l mm before / after "
        "predicted / after executed |\n|---|---|---|"
    )
    for p in report.poses:
        x = after[p.name]
        print(
            f"| {p.name} | {p.before.ap_p_mm:.4f} / {p.after.ap_p_mm:.4f} / {x.ap_p_mm:.4f} "
            f"| {p.before.rp_l_mm:.4f} / {p.after.rp_l_mm:.4f} / {x.rp_l_mm:.4f} |"
        )


if __name__ == "__main__":
    main()
