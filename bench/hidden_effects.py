"""Hidden-effect study of the gap workflow: is the missing effect named, and nothing else?

For every effect of the vocabulary, simulated datasets contain exactly that effect (plus
noise) while the starting model lacks it (start ``geometric`` for the non-geometric effects,
``nominal`` for geometric / base_frame / tool_frame), at three magnitudes relative to the noise
floor (the effect's mean position contribution = 0.15x, 0.5x and 3x the floor), over several
seeds; plus nothing-missing datasets for both starts. Prints the confusion matrix (true vs
named), recovery rates, false alarms, held-out error after adding the named effect and the
runtime per dataset, as Markdown.

    .venv/bin/python bench/hidden_effects.py            # 5 seeds, 500 points per dataset
    .venv/bin/python bench/hidden_effects.py --seeds 2 --n 300
"""

from __future__ import annotations

import argparse
import time

import numpy as np

from kinematics.description import load_description
from kinematics.effects import EFFECTS
from kinematics.gap.workflow import GapConfig, run_gap
from sim_sources.cell import simulate
from sim_sources.scenarios import get_scenario

FOLDED = ("geometric", "base_frame", "tool_frame")
MAGNITUDES = {"faint": 0.15, "weak": 0.5, "strong": 3.0}


def contribution_scale(name: str, n: int) -> float:
    """The scale at which effect ``name`` moves the probe by 1x the noise floor on average."""
    ds = simulate(get_scenario(name, scale=1.0), n, 1000)
    cols = [f"true_{name}_d{c}" for c in "xyz"]
    mean = float(np.linalg.norm(ds.table[cols].to_numpy(float), axis=1).mean())
    return ds.meta.noise_floor_m / mean


def one(scenario: str, scale: float, seed: int, n: int, start: str) -> dict:
    return one_dataset(get_scenario(scenario, scale=scale), seed, n, start)


def one_dataset(scenario, seed: int, n: int, start: str) -> dict:
    ds = simulate(scenario, n, seed)
    t0 = time.perf_counter()
    result = run_gap(load_description(ds.meta.robot), ds, GapConfig(start=start, seed=seed))
    floor_mm = ds.meta.noise_floor_m * 1e3
    return {
        "named": [e.effect for e in result.named],
        "before_ratio": result.stages[0].heldout.mean_mm / floor_mm,
        "after_ratio": result.stages[-1].heldout.mean_mm / floor_mm,
        "seconds": time.perf_counter() - t0,
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", type=int, default=5)
    parser.add_argument("--n", type=int, default=500)
    args = parser.parse_args()
    names = list(EFFECTS)
    runs = []
    for name in names:
        unit = contribution_scale(name, args.n)
        start = "nominal" if name in FOLDED else "geometric"
        for label, factor in MAGNITUDES.items():
            for seed in range(args.seeds):
                r = one(name, unit * factor, seed, args.n, start)
                runs.append({"true": name, "magnitude": label, "start": start, **r})
                print(
                    f"{name:18s} {label:6s} seed {seed}: named {r['named']} "
                    f"before {r['before_ratio']:.2f}x after {r['after_ratio']:.2f}x "
                    f"({r['seconds']:.1f} s)",
                    flush=True,
                )
    for start, scenario in (("geometric", "geometric"), ("nominal", "nominal")):
        for seed in range(2 * args.seeds):
            r = one_dataset(get_scenario(scenario, noise=True), 500 + seed, args.n, start)
            runs.append({"true": "none", "magnitude": "-", "start": start, **r})
            print(
                f"nothing missing ({start}) seed {seed}: named {r['named']} "
                f"after {r['after_ratio']:.2f}x ({r['seconds']:.1f} s)",
                flush=True,
            )
    report(runs, names, args)


def report(runs: list[dict], names: list[str], args) -> None:
    cols = [*names, "none"]
    print(
        f"\n### Confusion matrix (first named effect), {args.seeds} seeds x "
        f"{len(MAGNITUDES)} magnitudes, {args.n} points\n"
    )
    print("| true \\ named | " + " | ".join(cols) + " | extra effects named |")
    print("|---" * (len(cols) + 2) + "|")
    for true in cols:
        rows = [r for r in runs if r["true"] == true]
        counts = {c: 0 for c in cols}
        extra = 0
        for r in rows:
            counts[r["named"][0] if r["named"] else "none"] += 1
            extra += max(0, len(r["named"]) - 1)
        print(f"| {true} | " + " | ".join(str(counts[c]) for c in cols) + f" | {extra} |")
    print("\n### Recovery per effect and magnitude\n")
    print(
        "| effect | start | magnitude | recovered (exactly this effect) | held-out before / floor "
        "| held-out after / floor | s per dataset |"
    )
    print("|---|---|---|---|---|---|---|")
    for name in names:
        for label in MAGNITUDES:
            rows = [r for r in runs if r["true"] == name and r["magnitude"] == label]
            ok = sum(r["named"] == [name] for r in rows)
            print(
                f"| {name} | {rows[0]['start']} | {label} ({MAGNITUDES[label]:g}x floor) | "
                f"{ok}/{len(rows)} | {np.mean([r['before_ratio'] for r in rows]):.2f} | "
                f"{np.mean([r['after_ratio'] for r in rows]):.2f} | "
                f"{np.mean([r['seconds'] for r in rows]):.1f} |"
            )
    strong = [r for r in runs if r["magnitude"] == "strong"]
    weak = [r for r in runs if r["magnitude"] == "weak"]
    faint = [r for r in runs if r["magnitude"] == "faint"]
    none = [r for r in runs if r["true"] == "none"]
    rec = np.mean([r["named"] == [r["true"]] for r in strong])
    rec_w = np.mean([r["named"] == [r["true"]] for r in weak])
    rec_f = np.mean([r["named"] == [r["true"]] for r in faint])
    alarms = np.mean([bool(r["named"]) for r in none])
    after = [r["after_ratio"] for r in strong if r["named"] == [r["true"]]]
    print(
        f"\nrecovery (strong, {MAGNITUDES['strong']:g}x floor): {100 * rec:.1f}% "
        f"of {len(strong)}; weak ({MAGNITUDES['weak']:g}x): {100 * rec_w:.1f}% of {len(weak)}; "
        f"faint ({MAGNITUDES['faint']:g}x): {100 * rec_f:.1f}% of {len(faint)}"
    )
    print(f"false alarms on nothing-missing datasets: {100 * alarms:.1f}% of {len(none)}")
    print(
        f"held-out mean error after adding the named effect (strong, recovered): "
        f"mean {np.mean(after):.3f}x, max {np.max(after):.3f}x the noise floor"
    )
    print(
        f"runtime per dataset: mean {np.mean([r['seconds'] for r in runs]):.1f} s, "
        f"max {np.max([r['seconds'] for r in runs]):.1f} s"
    )


if __name__ == "__main__":
    main()
