"""Streamed vs offline on a real robot: UR10 Series A through ``robocal run`` (a dataset
source at ``--speed``, the window's settled check and event-time join, the learner stage)
against ``robocal continual`` on the same points, both scored on the same held-out points.

The daemon's learner holds out every 10th point by arrival and learns the rest in its window's
batches of 100 (90 training points each); the offline run gets exactly those training points
in the same order (``--test-fraction 0``) with ``--init 90 --batch 90``, so both learners see
the same batches. Both final models are scored by ``evaluate_on_dataset`` on the held-out rows.
Both learners screen their points with the quarantine (``learner.quarantine``): the daemon's
screens a window batch before its hold-out split, the offline one each training batch.

    .venv/bin/python bench/dataset_stream.py [--series ../shared/data/ur10-ipa/Series_A]
        [--rows 11900] [--speed 100] [--memory 500] [--base auto] [--out /tmp/dataset_stream]
"""

from __future__ import annotations

import argparse
import json
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

from kinematics.dataset import read_dataset, write_dataset
from kinematics.description import description_to_toml, load_description
from learner.snapshot import snapshot_from_bytes
from learner.workflow import evaluate_on_dataset
from stream.bus import BusConfig, free_port, open_session
from stream.config_render import loopback_config, write_config
from wire import Diagnostics, Metrics, decode, decode_model, key

ROBOCAL = str(Path(sys.executable).with_name("robocal"))
HERE = Path(__file__).resolve().parents[1]
CELL, ROBOT, HOLDOUT, BATCH = "bench", "ur10", 10, 100
STALL_S = 300.0  # no batch learned for this long (s): the stream is over


def run(cmd: list[str]) -> dict:
    out = subprocess.run(cmd, capture_output=True, text=True, check=False)
    if out.returncode != 0:
        raise SystemExit(f"{' '.join(cmd)} failed: {out.stderr.strip()[-500:]}")
    return json.loads(out.stdout) if "--json" in cmd else {}


def prepare(series: Path, rows: int, out: Path) -> tuple[Path, Path, Path, Path]:
    """Import the series; the first ``rows`` rows, their training and held-out parts, and the
    UR10 description with the series' probe as its tool (what ``robocal continual`` labels
    against: the nominal model with the dataset's ``T_6_S``)."""
    full = out / "series.parquet"
    run([ROBOCAL, "import", "ipa", str(series), "--out", str(full)])
    ds = read_dataset(full)
    ds = ds.subset(np.arange(min(rows, len(ds))))
    k = np.arange(len(ds))
    test = (k % HOLDOUT) == HOLDOUT - 1
    paths = out / "stream.parquet", out / "train.parquet", out / "test.parquet"
    write_dataset(ds, paths[0])
    write_dataset(ds.subset(np.flatnonzero(~test)), paths[1])
    write_dataset(ds.subset(np.flatnonzero(test)), paths[2])
    desc = load_description("ur10").with_tool(np.asarray(ds.meta.T_6_S, dtype=float))
    description = out / "ur10_series.toml"
    description.write_text(description_to_toml(desc))
    return (*paths, description)


def offline(train: Path, test: Path, memory: int, base: str, out: Path) -> tuple[dict, float]:
    start = time.perf_counter()
    model = out / "continual.safetensors"
    tb = str(BATCH - BATCH // HOLDOUT)
    run(
        [
            ROBOCAL,
            "continual",
            "--data",
            str(train),
            "--test-fraction",
            "0",
            "--seed",
            "0",
            "--memory",
            str(memory),
            "--batch",
            tb,
            "--init",
            tb,
            "--out",
            str(model),
            "--base",
            base,
            "--json",
        ]
    )
    elapsed = time.perf_counter() - start
    return run([ROBOCAL, "evaluate", "--model", str(model), "--data", str(test), "--json"]), elapsed


def streamed(
    data: Path, test: Path, description: Path, n_batches: int, args, out: Path
) -> tuple[dict, float, dict]:
    port = free_port()
    robot = {"name": ROBOT, "description": str(description), "stages": ["window", "learner"]}
    train_batch = BATCH - BATCH // HOLDOUT
    source = {
        "kind": "dataset",
        "path": str(data),
        "speed": args.speed,
        "period_s": 1.0,  # Series A's export has no usable time (it goes back): one visit per s
        "joint_rate_hz": 20.0,
        "temperature_rate_hz": 2.0,
    }
    raw = loopback_config(
        CELL,
        port,
        robot,
        torch_threads=1,
        shutdown_timeout_s=30.0,
        window={"batch_size": BATCH},
        learner={
            "holdout_every": HOLDOUT,
            "seed": 0,
            "continual": {
                "memory": args.memory,
                "batch": train_batch,
                "init": train_batch,
                "base": args.base,
            },
        },
        sources=[source],
    )
    cfg = write_config(out / "robocal.toml", raw)
    client = open_session(BusConfig.loopback(port, listen=False))
    metrics, models, diags = [], [], {}
    subs = [
        client.declare_subscriber(
            key(CELL, ROBOT, "metrics"),
            lambda s: metrics.append(decode(s.payload.to_bytes(), Metrics)),
        ),
        client.declare_subscriber(
            key(CELL, ROBOT, "model"), lambda s: models.append(s.payload.to_bytes())
        ),
        client.declare_subscriber(
            key(CELL, ROBOT, "diagnostics"),
            lambda s: diags.__setitem__((d := decode(s.payload.to_bytes(), Diagnostics)).stage, d),
        ),
    ]
    start = time.perf_counter()
    proc = subprocess.Popen(
        [ROBOCAL, "run", "--config", str(cfg)], stderr=subprocess.PIPE, text=True
    )
    try:
        deadline = time.monotonic() + args.timeout_s
        progress = (-1, time.monotonic())  # batches learned, when that last changed
        while "learner" not in diags or diags["learner"].accepted < n_batches:
            if proc.poll() is not None or time.monotonic() > deadline:
                raise SystemExit(f"daemon ended or timed out: {proc.stderr.read()[-800:]}")
            done = diags["learner"].accepted if "learner" in diags else 0
            if done != progress[0]:
                progress = (done, time.monotonic())
            elif time.monotonic() - progress[1] > STALL_S:
                break  # the window sent fewer full batches (a point it could not join)
            time.sleep(0.5)
        elapsed = time.perf_counter() - start
        time.sleep(1.5)  # the model and the last diagnostics of every stage
        header, snap = decode_model(max(models, key=lambda m: decode_model(m)[0].model_version))
        proc.send_signal(signal.SIGTERM)
        code = proc.wait(120)
    finally:
        if proc.poll() is None:
            proc.kill()
        for sub in subs:
            sub.undeclare()
        client.close()
    report = evaluate_on_dataset(snapshot_from_bytes(snap), read_dataset(test)).to_dict()
    info = {
        "model_version": header.model_version,
        "batches_learned": diags["learner"].accepted,
        "n_seen": metrics[-1].n_seen if metrics else 0,
        "quarantined": getattr(metrics[-1], "quarantined", None) if metrics else None,
        "exit_code": code,
        "diagnostics": {
            s: {"accepted": d.accepted, "dropped": d.dropped} for s, d in diags.items()
        },
    }
    return report, elapsed, info


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--series", default=str(HERE.parent / "shared/data/ur10-ipa/Series_A"))
    parser.add_argument("--rows", type=int, default=11900, help="a multiple of 100: full batches")
    parser.add_argument("--speed", type=float, default=100.0, help="x recorded (re-timed) time")
    parser.add_argument("--memory", type=int, default=500, help="N_m of both learners")
    parser.add_argument("--base", default="auto", help="physics base of both learners")
    parser.add_argument("--timeout-s", type=float, default=3600.0)
    parser.add_argument("--out", default="/tmp/dataset_stream")
    args = parser.parse_args()
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    data, train, test, description = prepare(Path(args.series), args.rows, out)
    n_train = len(read_dataset(train))
    n_batches = len(read_dataset(data)) // BATCH
    off, t_off = offline(train, test, args.memory, args.base, out)
    on, t_on, info = streamed(data, test, description, n_batches, args, out)
    ratio = on["mean_mm"] / off["mean_mm"]
    print(json.dumps({"offline": off, "streamed": on, "stream": info}, indent=1))
    print(
        f"\n{n_train} training / {len(read_dataset(test))} held-out points, N_m={args.memory}, "
        f"base {args.base}, "
        f"speed {args.speed:g}x"
    )
    print("| run | mean mm | max mm | p95 mm | mean arcmin | coverage 90 % | wall s |")
    print("|---|---|---|---|---|---|---|")
    for name, r, t in (("robocal continual", off, t_off), ("robocal run (streamed)", on, t_on)):
        print(
            f"| {name} | {r['mean_mm']:.4f} | {r['max_mm']:.4f} | {r['p95_mm']:.4f} | "
            f"{r['mean_arcmin']:.3f} | {r['coverage_90']:.3f} | {t:.0f} |"
        )
    print(
        f"streamed / offline mean: {ratio:.4f} ({'within' if abs(ratio - 1) <= 0.05 else 'OUTSIDE'}"
        " ±5 %)"
    )


if __name__ == "__main__":
    main()
