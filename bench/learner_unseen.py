"""Learner accuracy on random robots nobody tuned for: the error models of ``learner_ur10.py``
(``robocal gap``'s model as a base among them) on random DH arms of ``sim_sources.unseen``
(5-7 axes, 1-16 thermometers with random names, secondary encoders or not).

Each arm is uncalibrated (a random geometric error, ``--geometric`` noise floors, about 0.8 mm
at 20) and has one non-geometric effect, in turn joint compliance, a periodic gear error,
thermal growth, or a joint error driven by another joint's angle, which the gap workflow has no
model for (``--effect`` noise floors, about 0.3 mm at 8): what geometric calibration leaves
on a real arm. One 90/10 split per arm (seed 0); each arm's models are trained with the arm's
seed, so the arms are the replicas. The plain MLP sees every feature the learner sees.

    .venv/bin/python bench/learner_unseen.py --points 600 3000
"""

import argparse
import json
import tempfile
import time

import numpy as np
import torch
from learner_ur10 import compare

from kinematics.dataset import read_dataset
from sim_sources.unseen import UnseenSpec, write_unseen

#: The non-geometric effects the arms take in turn: the kinds real arms show after calibration,
#: and one no model of the product names (the network's own job).
EFFECTS = ("joint_compliance", "gear_periodic", "thermal_expansion", "joint_coupling")
#: Columns of the table; the default, ``robocal train``'s ``--base best``, is the last: of the
#: two residual models before it, the gap one where its validation error is clearly lower.
MODELS = (
    "geometric_calibration",
    "gap_model",
    "learner_only",
    "base_plus_residual",
    "plain_mlp",
    "gap_base_plus_residual",
    "best_on_validation",
)
CANDIDATES = ("base_plus_residual", "gap_base_plus_residual")


def arm_spec(seed: int, n_points: int, geometric: float = 20.0, effect: float = 8.0) -> UnseenSpec:
    """Random arm ``seed``: a geometric error of ``geometric`` noise floors and the hidden
    effect of :data:`EFFECTS` its seed picks, of ``effect`` noise floors (the benches' arms)."""
    return UnseenSpec(
        seed=seed,
        n_points=n_points,
        hidden=EFFECTS[seed % len(EFFECTS)],
        magnitude=effect,
        also=(("geometric", geometric),),
    )


def arm(seed: int, n_points: int, geometric: float, effect: float, epochs: int) -> dict:
    """One random arm's campaign and the models' test statistics on it."""
    spec = arm_spec(seed, n_points, geometric, effect)
    with tempfile.TemporaryDirectory() as folder:
        path, desc, truth = write_unseen(spec, folder)
        t0 = time.perf_counter()
        out = compare(read_dataset(path), [seed], epochs, mlp_inputs="all")
    about = {"arm": seed, "n_points": n_points, "effect": spec.hidden, "n_axes": desc.n_joints}
    about |= {"thermometers": len(truth["thermometers"]), "secondary": truth["secondary"]}
    return about | out | {"wall_s": time.perf_counter() - t0}


def table(rows: list[dict]) -> str:
    """A markdown table of test mean mm (90 % coverage) per arm and model, and the means."""
    head = "| arm | points | axes | effect | gap named | no model | " + " | ".join(MODELS) + " |"
    lines = [head, "|" + "---|" * (6 + len(MODELS))]
    for r in rows:
        cells = [f"{r[m]['mean_mm']:.3f}" + _coverage(r[m]) for m in MODELS]
        lines.append(
            f"| {r['arm']} | {r['n_points']} | {r['n_axes']} | {r['effect']} | "
            f"{r['gap_model']['named'] or '-'} | "
            f"{r['frames_only']['mean_mm']:.3f} | " + " | ".join(cells) + " |"
        )
    for n in sorted({r["n_points"] for r in rows}):
        sub = [r for r in rows if r["n_points"] == n]
        cells = [f"{np.mean([r[m]['mean_mm'] for r in sub]):.3f}" for m in MODELS]
        picked = sum(
            r[MODELS[-1]]["mean_mm"] <= min(r[m]["mean_mm"] for m in CANDIDATES) for r in sub
        )
        lines.append(
            f"| mean of {len(sub)} | {n} | | | the better base kept on {picked}/{len(sub)} | "
            f"{np.mean([r['frames_only']['mean_mm'] for r in sub]):.3f} | "
            + " | ".join(cells)
            + " |"
        )
    return "\n".join(lines)


def _coverage(stats: dict) -> str:
    return f" ({stats['coverage_90']:.0%})" if "coverage_90" in stats else ""


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--arms", nargs="+", type=int, default=list(range(8)))
    ap.add_argument("--points", nargs="+", type=int, default=[600, 3000])
    ap.add_argument("--geometric", type=float, default=20.0, help="noise floors")
    ap.add_argument("--effect", type=float, default=8.0, help="noise floors")
    ap.add_argument("--max-epochs", type=int, default=300)
    ap.add_argument("--json", help="also write the rows here")
    args = ap.parse_args()
    torch.set_num_threads(1)
    rows = []
    for n in args.points:
        for seed in args.arms:
            rows.append(arm(seed, n, args.geometric, args.effect, args.max_epochs))
            print(json.dumps(rows[-1], default=float), flush=True)
    if args.json:
        with open(args.json, "w") as f:
            json.dump(rows, f, indent=1, default=float)
    print(table(rows))


if __name__ == "__main__":
    main()
