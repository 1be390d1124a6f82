"""Compressed soak (issue 19): a day of a simulated cell (one visit every ``--period`` s, joints
at ``--joint-hz`` around each visit, temperatures once a minute) streamed ``--speed`` x faster
than real time through a ``robocal run`` daemon (window, learner, recorder) on loopback Zenoh.
The daemon's RSS, OS threads and open file descriptors (/proc/<pid>) are sampled every
``--every`` s; the report gives first/last/max and the RSS slope over the second half, the
samples published and lost (``missed``), and the models learned.

    .venv/bin/python bench/soak.py [--hours 24] [--period 30] [--joint-hz 8] [--speed 360]
"""

from __future__ import annotations

import argparse
import json
import tempfile
import threading
import time
from pathlib import Path

import numpy as np
from load import ROBOT, Daemon, proc_status

from sim_sources.cell import simulate
from sim_sources.scenarios import get_scenario
from sim_sources.streaming import StreamingConfig
from stream.sources import SimCellSource
from wire import key


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--hours", type=float, default=24.0, help="source time streamed (h)")
    parser.add_argument("--period", type=float, default=30.0, help="one visit every (s)")
    parser.add_argument("--joint-hz", type=float, default=8.0)
    parser.add_argument("--speed", type=float, default=360.0, help="x real time")
    parser.add_argument("--every", type=float, default=5.0, help="sampling period (s, wall)")
    parser.add_argument("--json", help="also write the results here")
    args = parser.parse_args()
    n = int(args.hours * 3600 / args.period)
    ds = simulate(get_scenario("paper"), n, 0)
    cfg = StreamingConfig(
        joint_rate_hz=args.joint_hz, temperature_rate_hz=1 / 60, period_s=args.period
    )
    with tempfile.TemporaryDirectory(prefix="robocal-soak-") as tmp:
        d = Daemon(Path(tmp), t_w_0=ds.meta.T_W_0)
        models: list[int] = []
        sub = d.client.declare_subscriber(key("load", ROBOT, "model"), lambda s: models.append(1))
        source = SimCellSource(d.client, "load", ROBOT, ds, cfg, speed=args.speed)
        feeder = threading.Thread(target=source.start)
        trace = []
        t0 = time.monotonic()
        feeder.start()
        while feeder.is_alive():
            st = proc_status(d.proc.pid)
            trace.append({"wall_s": round(time.monotonic() - t0, 1), **st})
            feeder.join(args.every)
        took = time.monotonic() - t0
        while d.window()[0] < source.published and time.monotonic() - t0 < took + 120:
            time.sleep(0.5)
        trace.append({"wall_s": round(time.monotonic() - t0, 1), **proc_status(d.proc.pid)})
        handled, drops = d.window()
        sub.undeclare()
        code = d.stop()
    half = trace[len(trace) // 2 :]
    slope = np.polyfit([p["wall_s"] for p in half], [p["VmRSS"] for p in half], 1)[0]
    source_h_per_wall_s = args.speed / 3600
    result = {
        "source_hours": args.hours,
        "wall_s": round(took, 1),
        "published": source.published,
        "per_s": round(source.published / took),
        "handled": handled,
        "missed": drops.get("missed", 0),
        "overload": drops.get("overload", 0),
        "models": len(models),
        "rss_mib": {
            "first": trace[0]["VmRSS"],
            "last": trace[-1]["VmRSS"],
            "max": max(p["VmRSS"] for p in trace),
            "slope_second_half_mib_per_source_h": round(slope / source_h_per_wall_s, 2),
        },
        "threads": {
            "first": trace[0]["Threads"],
            "last": trace[-1]["Threads"],
            "max": max(p["Threads"] for p in trace),
        },  # fmt: skip
        "fds": {
            "first": trace[0]["fds"],
            "last": trace[-1]["fds"],
            "max": max(p["fds"] for p in trace),
        },  # fmt: skip
        "exit_code": code,
    }
    print(json.dumps(result))
    if args.json:
        Path(args.json).write_text(json.dumps({**result, "trace": trace}, indent=1))


if __name__ == "__main__":
    main()
