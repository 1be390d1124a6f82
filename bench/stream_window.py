"""Windowing throughput in-process: samples/s through the event-time join and batcher.

    .venv/bin/python bench/stream_window.py [--n 400]

Two numbers: the join alone (decoded samples), and decode + validate + join (JSON payloads,
what the window stage does per message).
"""

from __future__ import annotations

import argparse
import time

from sim_sources.cell import simulate
from sim_sources.scenarios import get_scenario
from sim_sources.streaming import StreamingConfig, cell_samples
from stream.window import Batcher, Joiner, WindowConfig
from wire import STREAM_TYPES, decode, encode

_KIND = {"JointSample": "joints", "TrackerSample": "tracker", "TemperatureSample": "temperature"}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--n", type=int, default=400, help="points in the sim campaign")
    args = parser.parse_args()
    ds = simulate(get_scenario("paper"), args.n, 0)
    samples = list(cell_samples(ds, StreamingConfig(period_s=1.5)))
    payloads = [(_KIND[type(s).__name__], encode(s)) for s in samples]
    cfg = WindowConfig(batch_size=100)
    for label, decoded in (("join only", True), ("decode + validate + join", False)):
        best = 0.0
        for _ in range(3):
            joiner, batcher = Joiner(cfg), Batcher(cfg.batch_size)
            start = time.perf_counter()
            if decoded:
                points = [p for s in samples for p in joiner.push(s)]
            else:
                points = [
                    p
                    for stream, raw in payloads
                    for p in joiner.push(decode(raw, STREAM_TYPES[stream]))
                ]
            points += joiner.flush()
            batcher.add(points)
            rate = len(samples) / (time.perf_counter() - start)
            best = max(best, rate)
        print(
            f"{label:26s}: {len(samples)} samples -> {len(points)} points, "
            f"best of 3: {best:,.0f} samples/s"
        )


if __name__ == "__main__":
    main()
