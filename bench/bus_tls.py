"""Bus throughput and latency with mutual TLS and access control against plain TCP, in one run.

Each variant is a router on loopback and two client sessions through it, as on a line:
``tcp`` (a plain router, no access control), ``tls`` (the shipped router config without its
access control) and ``tls+acl`` (deploy/zenohd.json5 as shipped). The tracker role publishes
``--n`` samples of each ``--sizes`` payload as fast as a reliable, blocking publisher goes
(throughput: first put to last receipt at the subscriber); then ``--pings`` round trips, tracker
-> learner -> tracker, one at a time (latency: round-trip time). Runs are interleaved across
the variants; each number is the median over ``--repeats`` runs. Zenoh's shared memory is off
in every session, so payloads cross the links as they do between machines.

    .venv/bin/python bench/bus_tls.py --json
"""

from __future__ import annotations

import argparse
import json
import statistics
import tempfile
import threading
import time
from pathlib import Path

import zenoh

from stream.bus import BusConfig, TlsConfig, free_port, publisher, zenoh_config
from stream.router import router_config
from stream.security import make_line_certs

ROUTER_CONFIG = Path(__file__).resolve().parents[1] / "deploy" / "zenohd.json5"
PING, PONG = "robocal/bench/r1/tracker", "robocal/bench/r1/points"


def _open(zc: zenoh.Config) -> zenoh.Session:
    """A session with Zenoh's shared memory off: every byte crosses the link (as between
    machines), so large payloads measure the link, not a local shortcut."""
    zc.insert_json5("transport/shared_memory/enabled", "false")
    return zenoh.open(zc)


def open_variant(variant: str, certs: Path) -> tuple[zenoh.Session, dict[str, zenoh.Session]]:
    """The router of ``variant`` and the tracker and learner sessions connected to it."""
    port = free_port()
    if variant == "tcp":
        ep = (f"tcp/127.0.0.1:{port}",)
        router = _open(zenoh_config(BusConfig(mode="router", listen=ep, multicast_scouting=False)))
        client = BusConfig(mode="client", connect=ep, multicast_scouting=False)
        return router, {r: _open(zenoh_config(client)) for r in ("tracker", "learner")}
    zc = router_config(ROUTER_CONFIG, (f"tls/127.0.0.1:{port}",), certs)
    if variant == "tls":
        zc.insert_json5("access_control/enabled", "false")
    router = _open(zc)
    clients = {}
    for role in ("tracker", "learner"):
        tls = TlsConfig(
            ca=str(certs / "ca.pem"),
            cert=str(certs / f"{role}.pem"),
            key=str(certs / f"{role}.key"),
        )
        clients[role] = _open(zenoh_config(BusConfig.loopback(port, listen=False, tls=tls)))
    return router, clients


def throughput(clients: dict[str, zenoh.Session], n: int, size: int) -> dict:
    """Samples/s and MB/s of ``n`` puts of ``size`` bytes, first put to last receipt."""
    times: list[float] = []
    done = threading.Event()

    def got(_sample: zenoh.Sample) -> None:
        times.append(time.perf_counter())
        if len(times) == n:
            done.set()

    sub = clients["learner"].declare_subscriber(PING, got)
    pub = publisher(clients["tracker"], PING)
    time.sleep(0.5)
    payload = bytes(size)
    t0 = time.perf_counter()
    for _ in range(n):
        pub.put(payload)
    complete = done.wait(120)
    sub.undeclare()
    pub.undeclare()
    per_s = len(times) / (times[-1] - t0)
    return {
        "size_bytes": size,
        "sent": n,
        "received": len(times),
        "complete": complete,
        "samples_per_s": round(per_s),
        "mb_per_s": round(per_s * size / 1e6, 2),
    }


def latency(clients: dict[str, zenoh.Session], pings: int, size: int) -> dict:
    """Round-trip times (µs) of ``pings`` one-at-a-time pings echoed by the learner session."""
    echo_pub = publisher(clients["learner"], PONG)
    echo = clients["learner"].declare_subscriber(PING, lambda s: echo_pub.put(s.payload))
    back = threading.Event()
    pong = clients["tracker"].declare_subscriber(PONG, lambda _s: back.set())
    pub = publisher(clients["tracker"], PING)
    time.sleep(0.5)
    payload, rtt = bytes(size), []
    for i in range(pings + 20):
        back.clear()
        t0 = time.perf_counter()
        pub.put(payload)
        if not back.wait(5.0):
            raise RuntimeError("a ping got no answer in 5 s")
        if i >= 20:  # warm-up pings are not counted
            rtt.append((time.perf_counter() - t0) * 1e6)
    for d in (echo, pong, pub, echo_pub):
        d.undeclare()
    q = statistics.quantiles(rtt, n=100)
    return {
        "size_bytes": size,
        "pings": pings,
        "rtt_median_us": round(statistics.median(rtt)),
        "rtt_p90_us": round(q[89]),
        "rtt_p99_us": round(q[98]),
    }


def _median_of(runs: list[dict]) -> dict:
    """Each numeric field's median over repeated runs (``complete``: all of them complete)."""
    out = dict(runs[0])
    for k, v in runs[0].items():
        if isinstance(v, bool):
            out[k] = all(r[k] for r in runs)
        elif isinstance(v, int | float) and k not in ("size_bytes", "sent", "pings"):
            out[k] = round(statistics.median(r[k] for r in runs), 2)
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--n", type=int, default=200000, help="small samples per throughput run")
    parser.add_argument("--sizes", default="256,65536", help="payload sizes (bytes)")
    parser.add_argument("--pings", type=int, default=1000, help="round trips per run")
    parser.add_argument("--repeats", type=int, default=5, help="runs per variant, interleaved")
    parser.add_argument("--json", action="store_true")
    args = parser.parse_args()
    sizes = [int(s) for s in args.sizes.split(",")]
    variants = ("tcp", "tls", "tls+acl")
    runs: dict[str, dict[str, list]] = {
        v: {"latency": [], **{s: [] for s in sizes}} for v in variants
    }
    with tempfile.TemporaryDirectory() as tmp:
        certs = Path(tmp)
        make_line_certs(certs, ("router", "tracker", "learner"))
        opened = {v: open_variant(v, certs) for v in variants}
        try:
            for _ in range(args.repeats):  # interleaved: a busy moment hits every variant
                for v in variants:
                    clients = opened[v][1]
                    for s in sizes:
                        n = args.n if s < 4096 else max(args.n // 10, 100)  # ~1 GB at 64 KiB
                        runs[v][s].append(throughput(clients, n, s))
                    runs[v]["latency"].append(latency(clients, args.pings, sizes[0]))
        finally:
            for router, clients in opened.values():
                for c in clients.values():
                    c.close()
                router.close()
    results = {
        v: {
            "throughput": [_median_of(runs[v][s]) for s in sizes],
            "latency": _median_of(runs[v]["latency"]),
        }
        for v in variants
    }
    results["repeats"] = args.repeats
    if args.json:
        print(json.dumps(results, indent=2))
        return
    for v in variants:
        lat, tp = results[v]["latency"], results[v]["throughput"]
        print(
            f"{v:8s} rtt median {lat['rtt_median_us']} us, p99 {lat['rtt_p99_us']} us; "
            + "; ".join(
                f"{t['size_bytes']} B: {t['samples_per_s']}/s {t['mb_per_s']} MB/s" for t in tp
            )
        )


if __name__ == "__main__":
    main()
