"""The gap workflow on robots it has never seen (issue 16): is the hidden effect named?

Every dataset is a random arm from :mod:`sim_sources.unseen` (5-7 axes, not among the shipped
robots, with or without link masses and secondary encoders, 1-16 thermometers with random
names), its data made by code that shares nothing with the workflow's effect models, and at
most one hidden effect of the vocabulary at ``magnitude`` times the noise floor (its mean
position contribution). The robot reaches the workflow only as a TOML file named by path in
the dataset's metadata, as a new user's would. Start ``geometric`` for the non-geometric
effects, ``nominal`` for geometric / base_frame / tool_frame. Reports recovery (exactly the
hidden effect named), false alarms on datasets with nothing missing, the held-out error after
naming against the floor, and the runtime per dataset, as Markdown.

    .venv/bin/python bench/gap_unseen.py                  # 5 seeds x 3 magnitudes, 400 points
    .venv/bin/python bench/gap_unseen.py --seeds 2 --magnitudes 3
"""

from __future__ import annotations

import argparse
import tempfile
import time
from pathlib import Path

import numpy as np

from kinematics.gap.files import gap_from_files
from kinematics.gap.workflow import GapConfig
from sim_sources.unseen import VOCABULARY, UnseenSpec, write_unseen

FOLDED = ("geometric", "base_frame", "tool_frame")


def one(spec: UnseenSpec, start: str, folder: Path) -> dict:
    """Write the campaign, run ``gap`` on the file; what was named and how far it closed."""
    path, _, truth = write_unseen(spec, folder / f"s{spec.seed}_{spec.hidden}_{spec.magnitude}")
    t0 = time.perf_counter()
    result = gap_from_files(path, config=GapConfig(start=start, seed=spec.seed))
    seconds = time.perf_counter() - t0
    floor = result.noise_floor.mean_m * 1e3
    return {
        "named": [e.effect for e in result.named if e.identified],
        "unnamed": [e.effect for e in result.named if not e.identified],
        "not_formed": [n for n, _ in result.not_formed],
        "before": result.stages[0].heldout.mean_mm / floor,
        "after": result.stages[-1].heldout.mean_mm / floor,
        "seconds": seconds,
        "axes": truth["n_axes"],
        "thermometers": len(truth["thermometers"]),
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", type=int, default=5)
    parser.add_argument("--n", type=int, default=400, help="points per dataset")
    parser.add_argument("--magnitudes", type=float, nargs="+", default=[0.5, 1.0, 3.0])
    parser.add_argument("--none", type=int, default=20, help="datasets with nothing missing")
    args = parser.parse_args()
    runs = []
    with tempfile.TemporaryDirectory() as tmp:
        folder = Path(tmp)
        for k, hidden in enumerate(VOCABULARY):
            start = "nominal" if hidden in FOLDED else "geometric"
            for magnitude in args.magnitudes:
                for s in range(args.seeds):
                    spec = UnseenSpec(
                        seed=1000 * k + s, n_points=args.n, hidden=hidden, magnitude=magnitude
                    )
                    r = one(spec, start, folder) | {"true": hidden, "magnitude": magnitude}
                    runs.append(r)
                    _say(r, spec.seed)
        for s in range(args.none):
            start = "geometric" if s % 2 == 0 else "nominal"
            spec = UnseenSpec(seed=90_000 + s, n_points=args.n)
            r = one(spec, start, folder) | {"true": "none", "magnitude": 0.0}
            runs.append(r)
            _say(r, spec.seed)
    report(runs, args)


def _say(r: dict, seed: int) -> None:
    print(
        f"{r['true']:18s} {r['magnitude']:4g}x seed {seed}: {r['axes']} axes, "
        f"{r['thermometers']} thermometers; named {r['named']} unnamed {r['unnamed']} "
        f"before {r['before']:.2f}x after {r['after']:.2f}x ({r['seconds']:.1f} s)",
        flush=True,
    )


def report(runs: list[dict], args) -> None:
    print(f"\n### Recovery per effect ({args.seeds} seeds, {args.n} points per dataset)\n")
    heads = " | ".join(f"{m:g}x floor" for m in args.magnitudes)
    print(f"| effect | {heads} | held-out after / floor at {max(args.magnitudes):g}x |")
    print("|---" * (len(args.magnitudes) + 2) + "|")
    for hidden in VOCABULARY:
        cells = []
        for m in args.magnitudes:
            rows = [r for r in runs if r["true"] == hidden and r["magnitude"] == m]
            cells.append(f"{sum(r['named'] == [hidden] for r in rows)}/{len(rows)}")
        top = [
            r["after"]
            for r in runs
            if r["true"] == hidden and r["magnitude"] == max(m for m in args.magnitudes)
        ]
        print(f"| {hidden} | {' | '.join(cells)} | {np.mean(top):.2f} (max {np.max(top):.2f}) |")
    strong = [r for r in runs if r["magnitude"] == max(args.magnitudes)]
    none = [r for r in runs if r["true"] == "none"]
    ok = [r for r in strong if r["named"] == [r["true"]]]
    wrong = [(r["true"], r["named"], r["unnamed"]) for r in strong if r["named"] != [r["true"]]]
    print(
        f"\nrecovery at {max(args.magnitudes):g}x the floor: {len(ok)}/{len(strong)} "
        f"({100 * len(ok) / max(len(strong), 1):.1f}%); misses: {wrong}"
    )
    print(
        f"false alarms with nothing missing: {sum(bool(r['named']) for r in none)}/{len(none)}; "
        f"unnamed corrections there: {sum(bool(r['unnamed']) for r in none)}"
    )
    after = [r["after"] for r in ok]
    if after:
        print(
            f"held-out after naming (recovered, {max(args.magnitudes):g}x): mean "
            f"{np.mean(after):.3f}x, max {np.max(after):.3f}x the floor"
        )
    sec = [r["seconds"] for r in runs]
    print(f"runtime per dataset: mean {np.mean(sec):.2f} s, max {np.max(sec):.2f} s")


if __name__ == "__main__":
    main()
