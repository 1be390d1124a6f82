"""Load held (issue 19): a ``robocal run`` daemon (window, learner, recorder) on loopback Zenoh
flooded on every input topic at multiples of a line's rates (joints 125 Hz, tracker 1 Hz,
temperature 1 Hz), then with 10 MB messages, then as fast as one publisher can go. Per phase:
samples offered and received, lost (gaps in the sources' numbering that the window counted as
``missed``), drops by reason (``overload``, ``too_large``) and the daemon's peak RSS, threads and
open files (from /proc/<pid>). Zero loss is ``missed == overload == 0``; a rate is held when,
besides, the window's backlog is gone within 2.5 s of the phase's end.

    .venv/bin/python bench/load.py [--seconds 5] [--factors 1 10 20 40] [--big 10] [--json F]
"""

from __future__ import annotations

import argparse
import json
import os
import signal
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

import numpy as np

from stream.bus import BusConfig, alive_stages, free_port, open_session, publisher
from stream.config_render import loopback_config, write_config
from wire import (
    Diagnostics,
    JointSample,
    TemperatureSample,
    TrackerSample,
    decode,
    encode,
    key,
)

ROBOT = "fanuc_m900ib700"
LINE_HZ = {"joints": 125.0, "tracker": 1.0, "temperature": 1.0}


def config(workdir: Path, port: int, t_w_0=None) -> dict:
    """The daemon's config: window and a small learner for ``ROBOT``, a recorder in ``workdir``."""
    robot = {"name": ROBOT, "description": ROBOT, "stages": ["window", "learner"]}
    if t_w_0 is not None:
        robot["T_W_0"] = np.asarray(t_w_0, dtype=float).tolist()
    return loopback_config(
        "load",
        port,
        robot,
        checkpoint_dir=f"{workdir}/state",
        shutdown_timeout_s=10.0,
        window={"batch_size": 20, "require_temperatures": False},
        learner={
            "model": {"hidden_layers": 1, "neurons": 16},
            "continual": {
                "memory": 100,
                "batch": 20,
                "init": 20,
                "epochs_per_update": 3,
                "init_epochs": 10,
            },
        },
        recorder={"path": f"{workdir}/load.mcap", "flush_interval_s": 1.0},
    )


def proc_status(pid: int) -> dict[str, float]:
    """RSS and peak RSS (MiB), OS threads and open file descriptors of process ``pid``."""
    out: dict[str, float] = {}
    for line in Path(f"/proc/{pid}/status").read_text().splitlines():
        name, _, value = line.partition(":")
        if name in ("VmRSS", "VmHWM"):
            out[name] = int(value.split()[0]) / 1024
        elif name == "Threads":
            out[name] = int(value)
    out["fds"] = len(os.listdir(f"/proc/{pid}/fd"))
    return out


class Daemon:
    """``robocal run`` in a subprocess with a config for this bench; its window's diagnostics."""

    def __init__(self, workdir: Path, t_w_0=None) -> None:
        self.port = free_port()
        cfg = write_config(workdir / "robocal.toml", config(workdir, self.port, t_w_0))
        self.log = (workdir / "daemon.jsonl").open("w")
        exe = str(Path(sys.executable).with_name("robocal"))
        self.proc = subprocess.Popen([exe, "run", "--config", str(cfg)], stderr=self.log)
        self.client = open_session(BusConfig.loopback(self.port, listen=False))
        self.diag: dict[str, Diagnostics] = {}
        self._sub = self.client.declare_subscriber(key("load", ROBOT, "diagnostics"), self._on_diag)
        deadline = time.monotonic() + 120
        while len(alive_stages(self.client, "load", 0.5)) < 3:
            if self.proc.poll() is not None or time.monotonic() > deadline:
                raise RuntimeError("the daemon did not start (see daemon.jsonl)")
            time.sleep(0.2)
        self.pubs = {
            s: publisher(self.client, key("load", ROBOT, s)) for s in (*LINE_HZ, "batches")
        }
        while not all(p.matching_status.matching for p in self.pubs.values()):
            time.sleep(0.05)

    def _on_diag(self, sample) -> None:
        d = decode(sample.payload.to_bytes(), Diagnostics)
        self.diag[d.stage] = d

    def window(self) -> tuple[int, dict[str, int]]:
        """The window's handled samples (accepted + dropped, not missed) and drops so far."""
        d = self.diag.get("window")
        if d is None:
            return 0, {}
        dropped = dict(d.dropped)
        return d.accepted + sum(dropped.values()) - dropped.get("missed", 0), dropped

    def stop(self) -> int:
        self._sub.undeclare()
        self.client.close()
        self.proc.send_signal(signal.SIGTERM)
        code = self.proc.wait(60)
        self.log.close()
        return code


class Flood:
    """Source samples of the three streams, numbered per stream, stamped with the wall clock."""

    def __init__(self) -> None:
        self.seq = dict.fromkeys(LINE_HZ, 0)

    def payload(self, stream: str) -> bytes:
        i, t = self.seq[stream], time.time()
        self.seq[stream] += 1
        if stream == "joints":
            return encode(JointSample(seq=i, t=t, q=(0.1, -0.2, 0.3, 0.0, 0.5, 0.0)))
        if stream == "tracker":
            return encode(TrackerSample(seq=i, t=t, xyz=(1.5, 0.1, 1.2), quat=(0.0, 0.0, 0.0, 1.0)))
        return encode(TemperatureSample(seq=i, t=t, names=("ambient",), values=(21.0,)))


def run_phase(d: Daemon, flood: Flood, rates: dict[str, float] | None, seconds: float) -> dict:
    """Publish at ``rates`` (samples/s per stream; None: as fast as possible) for ``seconds``,
    wait until the window has caught up, and report the phase's counts and peak RSS."""
    before, drops0 = d.window()
    sent = dict.fromkeys(LINE_HZ, 0)
    peak = {"VmRSS": 0.0, "Threads": 0, "fds": 0}
    stop = threading.Event()

    def watch() -> None:
        while not stop.wait(0.1):
            st = proc_status(d.proc.pid)
            for k in peak:
                peak[k] = max(peak[k], st[k])

    watcher = threading.Thread(target=watch, daemon=True)
    watcher.start()
    t0 = time.monotonic()
    while (now := time.monotonic() - t0) < seconds:
        for stream in LINE_HZ:
            # unpaced: as fast as one publisher goes, the streams in a line's proportions
            due = int(now * rates[stream]) + 1 if rates else sent[stream] + LINE_HZ[stream]
            while sent[stream] < due:
                d.pubs[stream].put(flood.payload(stream))
                sent[stream] += 1
        if rates:
            time.sleep(0.001)
    took = time.monotonic() - t0
    offered = sum(sent.values())
    deadline = time.monotonic() + 180
    while True:  # until the window has handled (or dropped) everything offered
        handled, drops = d.window()
        if handled - before >= offered or time.monotonic() > deadline:
            break
        time.sleep(0.25)
    backlog_s = time.monotonic() - t0 - took
    stop.set()
    watcher.join()
    delta = {r: drops.get(r, 0) - drops0.get(r, 0) for r in ("missed", "overload", "too_large")}
    return {
        "rates": rates or "max",
        "seconds": round(took, 2),
        "offered": offered,
        "offered_per_s": round(offered / took),
        "received": handled - before,
        **delta,
        "backlog_s": round(backlog_s, 1),
        "zero_loss": delta["missed"] == 0 and delta["overload"] == 0,
        "kept_up": backlog_s <= 2.5,  # diagnostics come once a second
        "peak_rss_mib": round(peak["VmRSS"], 1),
        "threads": peak["Threads"],
        "fds": peak["fds"],
    }


def big_messages(d: Daemon, n: int, size: int) -> dict:
    """``n`` payloads of ``size`` bytes on every input topic and on ``batches``."""
    before = {s: (x.dropped.get("too_large", 0) if x else 0) for s, x in _stages(d).items()}
    blob = b'{"schema":"robocal.joints","pad":"' + b"x" * size + b'"}'
    peak = 0.0
    for _ in range(n):
        for pub in d.pubs.values():
            pub.put(blob)
        peak = max(peak, proc_status(d.proc.pid)["VmRSS"])
    time.sleep(3.0)  # two diagnostics periods
    after = {s: (x.dropped.get("too_large", 0) if x else 0) for s, x in _stages(d).items()}
    return {
        "messages": n * len(d.pubs),
        "size_mb": round(size / 1e6, 1),
        "too_large": {s: after[s] - before[s] for s in after},
        "peak_rss_mib": round(max(peak, proc_status(d.proc.pid)["VmRSS"]), 1),
        "alive": d.proc.poll() is None,
    }


def _stages(d: Daemon) -> dict[str, Diagnostics | None]:
    return {s: d.diag.get(s) for s in ("window", "learner")}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seconds", type=float, default=5.0, help="length of each phase (s)")
    parser.add_argument("--factors", type=float, nargs="+", default=[1, 10, 20, 40])
    parser.add_argument("--max-seconds", type=float, default=12.0, help="the unpaced phase (s)")
    parser.add_argument("--big", type=int, default=10, help="10 MB messages per topic")
    parser.add_argument("--json", help="also write the results here")
    parser.add_argument("--dir", help="keep the daemon's config, log, state and MCAP here")
    args = parser.parse_args()
    results: dict = {"phases": []}
    with tempfile.TemporaryDirectory(prefix="robocal-load-") as tmp:
        if args.dir:
            tmp = args.dir
            Path(tmp).mkdir(parents=True, exist_ok=True)
        d = Daemon(Path(tmp))
        flood = Flood()
        try:
            results["idle"] = proc_status(d.proc.pid)
            for f in args.factors:
                rates = {s: hz * f for s, hz in LINE_HZ.items()}
                res = {"factor": f, **run_phase(d, flood, rates, args.seconds)}
                print(json.dumps(res), flush=True)
                results["phases"].append(res)
            results["big"] = big_messages(d, args.big, 10_000_000)
            print(json.dumps({"big": results["big"]}), flush=True)
            res = {"factor": "max", **run_phase(d, flood, None, args.max_seconds)}
            print(json.dumps(res), flush=True)
            results["phases"].append(res)
        finally:
            results["exit_code"] = d.stop()
        events = [json.loads(x) for x in Path(tmp, "daemon.jsonl").read_text().splitlines()]
        stopped = [e for e in events if e.get("event") == "daemon_stopped"]
        results["summary"] = stopped[-1]["counts"] if stopped else None
        results["stage_failed"] = [e for e in events if e.get("event") == "stage_failed"]
    held = [p for p in results["phases"] if p["zero_loss"] and p["kept_up"]]
    results["max_zero_loss_per_s"] = max((p["offered_per_s"] for p in held), default=0)
    print(json.dumps({k: results[k] for k in ("max_zero_loss_per_s", "exit_code", "summary")}))
    if args.json:
        Path(args.json).write_text(json.dumps(results, indent=1))


if __name__ == "__main__":
    main()
