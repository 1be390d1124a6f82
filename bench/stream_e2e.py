"""End to end over Zenoh on loopback: sustained rate with zero loss, and the latency from a
tracker sample to its published data point.

    .venv/bin/python bench/stream_e2e.py [--n 300] [--latency-points 20] [--speeds 20 40 80 max]

Rate: a sim campaign is published by a source session at several speed factors (and as fast
as possible) into the window stage of a daemon session; zero loss means every published
sample was received and the window emitted exactly the points an offline join of the same
samples gives. Latency: in real time (speed 1), wall time from publishing a tracker sample to
receiving its data point on ``.../points``, for the default window (allowed lateness 0.5 s,
temperatures joined as-of, so a point also waits for the next 1 Hz temperature sample) and for
a joints-only window with 0.05 s lateness.
"""

from __future__ import annotations

import argparse
import threading
import time

import numpy as np

from sim_sources.cell import simulate
from sim_sources.scenarios import get_scenario
from sim_sources.streaming import StreamingConfig, cell_samples
from stream.bus import BusConfig, free_port, open_session
from stream.log import JsonLogger
from stream.sources import SimCellSource
from stream.stages import WindowStage
from stream.window import Joiner, WindowConfig
from wire import DataPoint, TrackerSample, decode, key

CELL = "bench"


class TimedSource(SimCellSource):
    """Records the wall time at which each tracker sample is published."""

    def __init__(self, *args, **kwargs) -> None:
        super().__init__(*args, **kwargs)
        self.tracker_wall: dict[int, float] = {}

    def publish(self, sample) -> None:
        if isinstance(sample, TrackerSample):
            self.tracker_wall[sample.seq] = time.perf_counter()
        super().publish(sample)


def run(ds, window: WindowConfig, streaming: StreamingConfig, speed: float | None) -> dict:
    port = free_port()
    server = open_session(BusConfig.loopback(port, listen=True))
    client = open_session(BusConfig.loopback(port, listen=False))
    robot = ds.meta.robot
    stage = WindowStage(server, CELL, robot, window, JsonLogger(stream=open("/dev/null", "w")))  # noqa: SIM115
    received: dict[int, float] = {}
    sub = client.declare_subscriber(
        key(CELL, robot, "points"),
        lambda s: received.setdefault(
            decode(s.payload.to_bytes(), DataPoint).seq, time.perf_counter()
        ),
    )
    time.sleep(0.5)
    source = TimedSource(client, CELL, robot, ds, streaming, speed)
    start = time.perf_counter()
    thread = threading.Thread(target=source.start)
    thread.start()
    thread.join()
    while stage.received < source.published and time.perf_counter() - start < 600:
        time.sleep(0.005)
    elapsed = time.perf_counter() - start
    stage.drain()
    live_points = stage.points
    stage.end_of_stream()
    time.sleep(0.2)
    offline = Joiner(window)
    expected = sum(len(offline.push(s)) for s in cell_samples(ds, streaming))
    latency = [received[k] - source.tracker_wall[k] for k in received if k in source.tracker_wall]
    sub.undeclare()
    stage.close()
    client.close()
    server.close()
    return {
        "published": source.published,
        "received": stage.received,
        "dropped": dict(stage.counter.dropped),
        "points_live": live_points,
        "points_expected": expected,
        "rate": source.published / elapsed,
        "latency": np.array(latency[:live_points]),
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--n", type=int, default=300, help="points for the rate runs")
    parser.add_argument(
        "--latency-points", type=int, default=20, help="points, real time (0: none)"
    )
    parser.add_argument(
        "--speeds", nargs="+", default=["20", "40", "80", "max"], help="x real time, or max"
    )
    args = parser.parse_args()
    ds = simulate(get_scenario("paper"), args.n, 0)
    streaming = StreamingConfig(period_s=1.5)
    window = WindowConfig(batch_size=100)
    print("sustained rate (source -> Zenoh loopback -> window stage):")
    for speed in (None if v == "max" else float(v) for v in args.speeds):
        r = run(ds, window, streaming, speed)
        loss = r["published"] - r["received"]
        ok = loss == 0 and r["points_live"] == r["points_expected"] and not r["dropped"]
        label = "as fast as possible" if speed is None else f"speed {speed:>4.0f}x"
        print(
            f"  {label:20s}: {r['published']} samples at {r['rate']:,.0f} samples/s, "
            f"lost {loss}, points {r['points_live']}/{r['points_expected']} "
            f"(+1 at end of stream), zero loss: {ok}"
        )
    if not args.latency_points:
        return
    small = simulate(get_scenario("paper"), args.latency_points, 1)
    rt = StreamingConfig(period_s=1.0)
    print("latency, tracker sample published -> data point received (real time):")
    for label, cfg in (
        ("default window", WindowConfig()),
        (
            "joints-only, lateness 0.05 s",
            WindowConfig(require_temperatures=False, allowed_lateness_s=0.05),
        ),
    ):
        lat = run(small, cfg, rt, 1.0)["latency"] * 1e3
        print(
            f"  {label:30s}: n={len(lat)}, p50 {np.percentile(lat, 50):.1f} ms, "
            f"p99 {np.percentile(lat, 99):.1f} ms, max {lat.max():.1f} ms"
        )


if __name__ == "__main__":
    main()
