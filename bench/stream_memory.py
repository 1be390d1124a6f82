"""Resident memory over a long stream: window + learner + dashboard + recorder stages of a daemon
fed over Zenoh loopback; RSS (VmRSS of /proc/PID/status, this process and the learner's training
process together) sampled as the stream goes.

    .venv/bin/python bench/stream_memory.py [--n 2000] [--out /tmp/robocal-mem]
"""

from __future__ import annotations

import argparse
import os
import threading
import time
from dataclasses import replace
from pathlib import Path

import numpy as np
import torch

from learner.config import ContinualConfig, ModelConfig
from sim_sources.cell import simulate
from sim_sources.scenarios import get_scenario
from sim_sources.streaming import StreamingConfig
from stream.bus import BusConfig, free_port, open_session
from stream.daemon import Daemon
from stream.demo import DEMO_LEARNER, demo_config
from stream.log import JsonLogger
from stream.sources import SimCellSource


def rss_mib() -> float:
    """VmRSS of this process and its children (the training process), MiB."""
    me = os.getpid()
    procs = [p for p in Path("/proc").iterdir() if p.name.isdigit()]
    total = 0
    for proc in [Path(f"/proc/{me}"), *(p for p in procs if _parent(p) == me)]:
        try:
            status = (proc / "status").read_text().splitlines()
        except OSError:  # ended meanwhile
            continue
        total += sum(int(line.split()[1]) for line in status if line.startswith("VmRSS:"))
    return total / 1024


def _parent(proc: Path) -> int | None:
    """The parent pid of /proc/PID (None if that process is gone)."""
    try:
        return int((proc / "stat").read_text().rsplit(")", 1)[1].split()[1])
    except (OSError, IndexError, ValueError):
        return None


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--n", type=int, default=2000, help="points in the stream")
    parser.add_argument("--out", default="/tmp/robocal-mem", help="folder for .rrd/.mcap")
    args = parser.parse_args()
    torch.set_num_threads(1)
    ds = simulate(get_scenario("paper"), args.n, 0)
    learner = replace(
        DEMO_LEARNER,
        model=ModelConfig(hidden_layers=1, neurons=32),
        continual=ContinualConfig(
            memory=200, batch=100, init=100, epochs_per_update=5, init_epochs=20
        ),
        max_test_points=100,
    )
    port = free_port()
    cfg = replace(
        demo_config(Path(args.out), "mem", ds.meta.robot, np.asarray(ds.meta.T_W_0), port),
        learner=learner,
    )
    daemon = Daemon(cfg, logger=JsonLogger(stream=open("/dev/null", "w"))).start()  # noqa: SIM115
    client = open_session(BusConfig.loopback(port, listen=False))
    time.sleep(0.5)
    source = SimCellSource(client, "mem", ds.meta.robot, ds, StreamingConfig(period_s=1.5), 200.0)
    thread = threading.Thread(target=source.start)
    thread.start()
    window = daemon.windows[ds.meta.robot]
    marks = []
    while thread.is_alive():
        thread.join(2.0)
        marks.append((window.points, window.received, rss_mib()))
    daemon.end_of_stream({ds.meta.robot: source.published})
    marks.append((window.points, window.received, rss_mib()))
    client.close()
    daemon.stop()
    print(f"{source.published} samples, {window.points} points; RSS (MiB) as the stream went:")
    for frac in (0.1, 0.25, 0.5, 0.75, 1.0):
        points, samples, rss = marks[min(int(frac * (len(marks) - 1)), len(marks) - 1)]
        print(f"  after {points:5d} points / {samples:7d} samples: {rss:7.1f}")
    half = [m[2] for m in marks[len(marks) // 2 :]]
    print(f"second half: min {min(half):.1f}, max {max(half):.1f} MiB")


if __name__ == "__main__":
    main()
