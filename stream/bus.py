"""Zenoh sessions from a frozen config, queue-fed workers and liveliness tokens.

By default a session is an embedded peer (no router needed on one machine); ``mode="client"``
with ``connect`` endpoints talks through routers (deploy/zenohd.json5); a client whose router
is killed and restarted reconnects by itself (zenoh's default connect retry; its subscriptions
come back, what was published meanwhile is lost and counted by the window as ``missed``:
tests/stream/test_faults.py). Zenoh callbacks only put ``Received`` items on a queue: a worker
thread does the work, so a callback never blocks the Zenoh runtime and never calls back into
Zenoh.
"""

from __future__ import annotations

import json
import os
import queue
import random
import socket
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, replace

import zenoh

from kinematics.errors import ConfigError

MODES = ("peer", "client", "router")


@dataclass(frozen=True, kw_only=True)
class TlsConfig:
    """Mutual TLS (PEM paths): the line's CA, this process's role certificate and its key.

    The certificate's common name is the role the router's access control knows it by
    (``robocal certs`` makes them; deploy/zenohd.json5 lists the roles).
    """

    ca: str
    cert: str
    key: str

    def check_files(self) -> None:
        """ConfigError naming the first file that cannot be read."""
        for name in ("ca", "cert", "key"):
            path = getattr(self, name)
            if not os.access(path, os.R_OK):
                raise ConfigError(f"bus.tls.{name}: cannot read {path!r}")


@dataclass(frozen=True, kw_only=True)
class BusConfig:
    """How to join the bus: mode, listen/connect endpoints (``tcp/host:port``, or
    ``tls/host:port`` with ``tls``), scouting; or a whole Zenoh config file (``zenoh_config``)."""

    mode: str = "peer"
    listen: tuple[str, ...] = ()
    connect: tuple[str, ...] = ()
    multicast_scouting: bool = True
    #: ``tls = {ca, cert, key}``: every endpoint is ``tls/`` and both ends show certificates.
    tls: TlsConfig | None = None
    #: A Zenoh JSON5 config file used as it is (the other bus keys must then be left out).
    zenoh_config: str | None = None

    def __post_init__(self) -> None:
        if isinstance(self.tls, dict):  # from TOML: tls = {ca = ..., cert = ..., key = ...}
            try:
                object.__setattr__(self, "tls", TlsConfig(**self.tls))
            except TypeError as exc:
                raise ConfigError(f"bus.tls needs ca, cert and key: {exc}") from None
        if self.zenoh_config is not None:
            if replace(self, zenoh_config=None) != BusConfig():
                raise ConfigError(
                    "bus.zenoh_config names a whole Zenoh config: leave the other bus keys "
                    "out (set them in the file)"
                )
            return
        if self.mode not in MODES:
            raise ConfigError(f"bus.mode must be one of {MODES}, got {self.mode!r}")
        if self.tls is not None and (self.mode != "client" or self.listen):
            # a peer would also listen and meet other peers directly, past the router's rules
            raise ConfigError(
                "bus.tls needs mode = 'client' and no listen endpoints: the router enforces "
                "the line's access control (deploy/zenohd.json5)"
            )
        for ep in (*self.listen, *self.connect):
            if "/" not in ep:
                raise ConfigError(f"bus endpoint must look like tcp/127.0.0.1:7447, got {ep!r}")
            if (self.tls is not None) != ep.startswith("tls/"):
                raise ConfigError(
                    f"bus endpoint {ep!r}: with bus.tls every endpoint is tls/host:port, "
                    "without it none is"
                )
        if self.mode == "client" and not self.connect and not self.multicast_scouting:
            raise ConfigError("bus.mode 'client' needs connect endpoints or multicast scouting")

    @classmethod
    def loopback(cls, port: int, listen: bool, tls: TlsConfig | None = None) -> BusConfig:
        """A test/demo config on ``tcp/127.0.0.1:<port>``, scouting off; with ``tls`` a client
        of the router on ``tls/127.0.0.1:<port>``."""
        ep = (f"{'tcp' if tls is None else 'tls'}/127.0.0.1:{port}",)
        return cls(
            mode="peer" if tls is None else "client",
            listen=ep if listen else (),
            connect=() if listen else ep,
            multicast_scouting=False,
            tls=tls,
        )


#: The kernel's ephemeral port range where it does not say (Linux's default).
EPHEMERAL_RANGE = (32768, 60999)


def ephemeral_range() -> tuple[int, int]:
    """The ports the kernel hands out to outgoing connections and binds to 0, first and last
    (Linux: ``ip_local_port_range``)."""
    try:
        with open("/proc/sys/net/ipv4/ip_local_port_range") as f:
            low, high = (int(v) for v in f.read().split()[:2])
            return low, high
    except (OSError, ValueError):
        return EPHEMERAL_RANGE


def free_port() -> int:
    """A TCP port on 127.0.0.1 that is free right now, drawn at random outside the kernel's
    ephemeral range (below it, else above it): a port the kernel hands out (a bind to 0) may
    be taken again by any outgoing connection before the caller listens on it (a CI run's
    daemon lost its port so, "Address already in use"); outside it only an explicit bind
    takes one."""
    low, high = ephemeral_range()
    span = (10000, low) if low - 10000 >= 1000 else (high + 1, 65536)
    if span[1] - span[0] < 1000:  # no room outside it: the kernel's choice
        with socket.socket() as s:
            s.bind(("127.0.0.1", 0))
            return s.getsockname()[1]
    draw = random.SystemRandom()
    for _ in range(200):
        port = draw.randrange(*span)
        with socket.socket() as s:
            try:
                s.bind(("127.0.0.1", port))
            except OSError:
                continue
            return port
    raise OSError(f"no free TCP port on 127.0.0.1 in {span[0]}-{span[1] - 1}")


def zenoh_config(cfg: BusConfig) -> zenoh.Config:
    """The Zenoh config of ``cfg`` (ConfigError for an unreadable file or certificate)."""
    if cfg.zenoh_config is not None:
        try:
            return zenoh.Config.from_file(cfg.zenoh_config)
        except (zenoh.ZError, OSError, ValueError) as exc:
            raise ConfigError(f"bus.zenoh_config {cfg.zenoh_config!r}: {exc}") from None
    zc = zenoh.Config()
    zc.insert_json5("mode", json.dumps(cfg.mode))
    zc.insert_json5("scouting/multicast/enabled", json.dumps(cfg.multicast_scouting))
    if cfg.listen:
        zc.insert_json5("listen/endpoints", json.dumps(list(cfg.listen)))
    if cfg.connect:
        zc.insert_json5("connect/endpoints", json.dumps(list(cfg.connect)))
    if cfg.tls is not None:
        cfg.tls.check_files()
        tls = {
            "root_ca_certificate": cfg.tls.ca,
            "connect_certificate": cfg.tls.cert,
            "connect_private_key": cfg.tls.key,
            "enable_mtls": True,
            "verify_name_on_connect": True,
        }
        zc.insert_json5("transport/link/tls", json.dumps(tls))
        # Shared memory would hand payloads to local processes beside the encrypted link.
        zc.insert_json5("transport/shared_memory/enabled", "false")
    return zc


class BusUnreachableError(ConfigError):
    """A client found none of its routers (down, not started yet, or refusing its certificate)."""


def open_session(cfg: BusConfig) -> zenoh.Session:
    """Open a Zenoh session configured by ``cfg`` (BusUnreachableError: a client's routers did
    not answer; ConfigError: anything else)."""
    zc = zenoh_config(cfg)
    try:
        return zenoh.open(zc)
    except zenoh.ZError as exc:
        error = BusUnreachableError if cfg.mode == "client" and cfg.connect else ConfigError
        raise error(f"cannot open Zenoh session ({cfg}): {exc}") from None


def publisher(session: zenoh.Session, key_expr: str) -> zenoh.Publisher:
    """A reliable publisher that blocks rather than drops when the network is congested; its
    samples name their encoding (JSON messages; a model is a framed binary snapshot)."""
    E = zenoh.Encoding
    return session.declare_publisher(
        key_expr,
        encoding=E.APPLICATION_OCTET_STREAM if key_expr.endswith("/model") else E.APPLICATION_JSON,
        congestion_control=zenoh.CongestionControl.BLOCK,
        reliability=zenoh.Reliability.RELIABLE,
    )


def wait_matched(
    publishers: list[zenoh.Publisher], timeout_s: float, stop: threading.Event | None = None
) -> list[str]:
    """Wait up to ``timeout_s`` (s), or until ``stop`` is set, for a subscriber on each of
    ``publishers``; the keys still without one (a put before a subscriber is known is lost)."""
    stop = stop or threading.Event()
    deadline = time.monotonic() + timeout_s
    while True:
        waiting = [str(p.key_expr) for p in publishers if not p.matching_status.matching]
        left = deadline - time.monotonic()
        if not waiting or left <= 0 or stop.wait(min(0.05, left)):
            return waiting


@dataclass(frozen=True)
class Received:
    """One sample as a worker sees it: key, payload, attachment and receive time (s, epoch)."""

    key: str
    payload: bytes
    attachment: bytes | None
    received_t: float


def _to_received(sample: zenoh.Sample) -> Received:
    att = sample.attachment
    return Received(
        str(sample.key_expr),
        sample.payload.to_bytes(),
        None if att is None else att.to_bytes(),
        time.time(),
    )


@dataclass(frozen=True)
class _Call:
    fn: Callable[[], None]
    done: threading.Event


class Worker:
    """A thread that calls ``handle(item)`` for each queued item; ``stop()`` drains and joins.

    ``idle(now)`` is called at least every ``tick_s`` (periodic work: flush, diagnostics). An
    exception that escapes ``handle`` or ``idle`` is fatal: it is kept in :attr:`error` and the
    thread ends (the owner's supervisor reports it and stops the process). The queue is
    bounded: a payload over ``max_payload_bytes`` is dropped before it is copied (counted in
    :attr:`too_large`), and beyond ``max_queue`` items or ``max_queue_bytes`` of payload waiting
    new samples are dropped (counted in :attr:`overload`), so a flood costs bounded memory.
    """

    def __init__(
        self,
        name: str,
        handle: Callable[[Received], None],
        idle: Callable[[float], None] | None = None,
        tick_s: float = 0.2,
        max_queue: int = 200_000,
        max_queue_bytes: int = 64 * 2**20,
        max_payload_bytes: int = 64 * 2**20,
    ) -> None:
        self.name = name
        self.queue: queue.Queue[Received | None] = queue.Queue(max_queue)
        self.max_queue_bytes, self.max_payload_bytes = max_queue_bytes, max_payload_bytes
        self.queued_bytes = 0
        self._bytes_lock = threading.Lock()
        self._handle = handle
        self._idle = idle
        self._tick = tick_s
        self._abort = threading.Event()
        self.error: BaseException | None = None
        self.overload = 0
        self.too_large = 0
        self.abandoned = 0
        self._thread = threading.Thread(target=self._loop, name=name, daemon=True)
        self._thread.start()

    @property
    def alive(self) -> bool:
        """Whether the thread still runs."""
        return self._thread.is_alive()

    def callback(self, sample: zenoh.Sample) -> None:
        """The Zenoh subscriber callback: enqueue only (drop and count when too large or full)."""
        self.offer(sample, self.max_payload_bytes)

    def offer(self, sample: zenoh.Sample, max_payload_bytes: int) -> None:
        """Enqueue ``sample`` unless its payload exceeds ``max_payload_bytes`` (``too_large``,
        refused before it is copied) or the queue is full (``overload``)."""
        n = len(sample.payload)
        with self._bytes_lock:
            if n > max_payload_bytes:
                self.too_large += 1
                return
            if self.queued_bytes + n > self.max_queue_bytes or self.queue.full():
                self.overload += 1
                return
            self.queued_bytes += n
        try:
            self.queue.put_nowait(_to_received(sample))
        except queue.Full:
            with self._bytes_lock:
                self.queued_bytes -= n
                self.overload += 1

    def _loop(self) -> None:
        next_idle = time.monotonic() + self._tick
        while True:
            try:
                item = self.queue.get(timeout=self._tick)
            except queue.Empty:
                item = ...
            if isinstance(item, Received):
                with self._bytes_lock:
                    self.queued_bytes -= len(item.payload)
            try:
                if item is None:
                    break
                if self._abort.is_set():
                    if isinstance(item, _Call):
                        item.done.set()
                    self.abandoned += item is not ...
                    continue
                if isinstance(item, _Call):
                    try:
                        item.fn()
                    finally:
                        item.done.set()
                elif item is not ...:
                    self._handle(item)
                if self._idle is not None and time.monotonic() >= next_idle:
                    next_idle = time.monotonic() + self._tick
                    self._idle(time.time())
            except BaseException as exc:  # fatal: kept for the supervisor; the thread ends
                self.error = exc
                return
            finally:
                if item is not ...:
                    self.queue.task_done()

    def submit(self, fn: Callable[[], None]) -> threading.Event:
        """Queue ``fn`` to run on the worker thread after what is queued; the returned event is
        set once it has run (or was abandoned). An exception it raises is fatal, as in
        ``handle``."""
        if self.error is not None or not self.alive:
            raise RuntimeError(f"worker {self.name} is not running ({self.error!r})")
        call = _Call(fn, threading.Event())
        self.queue.put(call)
        return call.done

    def call(self, fn: Callable[[], None], timeout_s: float = 60.0) -> None:
        """Run ``fn`` on the worker thread after what is queued; wait for it."""
        done = self.submit(fn)
        deadline = time.monotonic() + timeout_s
        while not done.wait(0.05):
            if self.error is not None or not self.alive:
                raise RuntimeError(f"worker {self.name} ended ({self.error!r})")
            if time.monotonic() > deadline:
                raise TimeoutError(f"worker did not run the call within {timeout_s} s")

    def drain(self, timeout_s: float = 30.0) -> bool:
        """Wait until every enqueued item is handled; False on timeout or a dead thread."""
        deadline = time.monotonic() + timeout_s
        while self.queue.unfinished_tasks and time.monotonic() < deadline:
            if self.error is not None or not self.alive:
                return False
            time.sleep(0.005)
        return not self.queue.unfinished_tasks

    def stop(self, timeout_s: float = 30.0) -> bool:
        """Handle what is queued within ``timeout_s``, abandon the rest (counted in
        :attr:`abandoned`), end the thread; False when it is still busy with one item."""
        try:
            self.queue.put(None, timeout=max(timeout_s, 0.01))
        except queue.Full:
            self._abort.set()
            self.queue.put(None)
        self._thread.join(max(timeout_s, 0.0))
        if self._thread.is_alive():
            self._abort.set()
            self._thread.join(1.0)
        return not self._thread.is_alive()


def subscribe(session: zenoh.Session, key_expr: str, worker: Worker) -> zenoh.Subscriber:
    """Subscribe ``worker`` to ``key_expr`` (samples land on its queue)."""
    return session.declare_subscriber(key_expr, worker.callback)


def liveliness_key(cell: str, robot: str, stage: str) -> str:
    return f"robocal/{cell}/{robot}/alive/{stage}"


def declare_alive(session: zenoh.Session, cell: str, robot: str, stage: str):
    """A liveliness token that tells others this stage is up (dropped when it ends)."""
    return session.liveliness().declare_token(liveliness_key(cell, robot, stage))


def alive_stages(session: zenoh.Session, cell: str = "*", timeout_s: float = 1.0) -> list[str]:
    """Keys of the live stage tokens under ``robocal/<cell>/**``."""
    out = []
    for reply in session.liveliness().get(f"robocal/{cell}/*/alive/*", timeout=timeout_s):
        if reply.ok is not None:
            out.append(str(reply.ok.key_expr))
    return sorted(out)
