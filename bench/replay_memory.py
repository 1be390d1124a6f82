"""Replay memory: peak RSS of ``robocal replay`` against the recording's size (issue 19 item 5).

    .venv/bin/python bench/replay_memory.py --mb 200

Writes a recording of 125 Hz joints samples with the recorder (``McapRecorder``: the daemon's
chunking and compression), then runs, each in a child process whose own peak RSS comes from
``os.wait4``: ``robocal replay`` of the whole file and of its first tenth (``--end``) to a
listening Zenoh session in this process that counts what arrives; the load-everything read that
replay used before this change (every message in a list, then sorted); and ``python -c pass``
with the same imports as the floor. Prints one JSON object.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from stream.bus import BusConfig, free_port, open_session
from stream.mcap_io import McapRecorder, RecordingReader

HZ = 125.0
LOAD_ALL = """
import sys
from mcap.reader import NonSeekingReader
with open(sys.argv[1], "rb") as f:
    out = [(c.topic, m.data, m.log_time, m.publish_time)
           for _, c, m in NonSeekingReader(f).iter_messages(log_time_order=False)]
out.sort(key=lambda r: r[2])
print(len(out))
"""
FLOOR = "import zenoh, mcap.reader, tqdm, stream.replay"


def write_recording(path: Path, mb: float, seed: int = 0) -> int:
    """A recording of joints samples until the file passes ``mb`` MiB; the message count."""
    rng = np.random.default_rng(seed)
    rec = McapRecorder(path, flush_interval_s=1.0, split_bytes=None)
    t0, n = 1.7e9, 0
    while n % 10_000 or path.stat().st_size < mb * 2**20:
        q = rng.uniform(-3.0, 3.0, 6).tolist()
        t = t0 + n / HZ
        payload = json.dumps(
            {"schema": "robocal.joints", "version": 1, "seq": n, "t": t, "q": q, "qs": None},
            separators=(",", ":"),
        ).encode()
        rec.add("robocal/cell1/r1/joints", payload, log_time_ns=int(t * 1e9))
        n += 1
    rec.close()
    return n


def peak_rss(argv: list[str]) -> tuple[float, float, str]:
    """Run ``argv`` under GNU time; its peak RSS (MiB), wall time (s) and stdout. (A child
    forked from this process would count this process's size in its own peak.)"""
    with tempfile.NamedTemporaryFile("r") as usage:
        start = time.perf_counter()
        proc = subprocess.run(
            ["/usr/bin/time", "-f", "%M", "-o", usage.name, *argv],
            capture_output=True,
            text=True,
        )
        wall = time.perf_counter() - start
        if proc.returncode != 0:
            raise SystemExit(f"{argv[:3]}... exited {proc.returncode}: {proc.stderr[-300:]}")
        return int(usage.read().split()[-1]) / 1024, wall, proc.stdout


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--mb", type=float, default=200.0, help="recording size to write (MiB)")
    args = ap.parse_args()
    robocal = str(Path(sys.executable).with_name("robocal"))
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "joints.mcap"
        start = time.perf_counter()
        n = write_recording(path, args.mb)
        write_s = time.perf_counter() - start
        reader = RecordingReader(path)
        stats = reader.summary.statistics
        span_s = (stats.message_end_time - stats.message_start_time) / 1e9
        port = free_port()
        listener = open_session(BusConfig.loopback(port, listen=True))
        received = [0]
        sub = listener.declare_subscriber(
            "robocal/**", lambda s: received.__setitem__(0, received[0] + 1)
        )
        runs = {}
        for name, extra in (
            ("replay_all", []),
            ("replay_first_tenth", ["--end", str(span_s / 10)]),
        ):
            received[0] = 0
            argv = [robocal, "replay", str(path), "--connect", f"tcp/127.0.0.1:{port}", "--json"]
            rss, wall, out = peak_rss(argv + extra)
            time.sleep(1.0)
            published = json.loads(out)["published"]
            runs[name] = {
                "peak_rss_mib": round(rss, 1),
                "wall_s": round(wall, 1),
                "published": published,
                "received": received[0],
                "msgs_per_s": round(published / wall),
            }
        sub.undeclare()
        listener.close()
        rss, wall, _ = peak_rss([sys.executable, "-c", LOAD_ALL, str(path)])
        runs["load_all_before"] = {"peak_rss_mib": round(rss, 1), "wall_s": round(wall, 1)}
        rss, _, _ = peak_rss([sys.executable, "-c", FLOOR])
        runs["imports_only"] = {"peak_rss_mib": round(rss, 1)}
        result = {
            "file_mib": round(path.stat().st_size / 2**20, 1),
            "messages": n,
            "recorded_span_h": round(span_s / 3600, 2),
            "payload_mib": round(_payload_mib(path), 1),
            "write_s": round(write_s, 1),
            **runs,
            "load_avg": os.getloadavg(),
        }
    print(json.dumps(result, indent=2))


def _payload_mib(path: Path) -> float:
    """The messages' payloads added up (MiB): what a load-everything reader holds at least."""
    return sum(len(r.payload) for r in RecordingReader(path).messages()) / 2**20


if __name__ == "__main__":
    main()
