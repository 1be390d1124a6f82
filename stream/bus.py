"""Zenoh sessions from a frozen config, publishers and liveliness tokens.

By default a session is an embedded peer (no router needed on one machine); ``mode="client"``
with ``connect`` endpoints talks through routers (deploy/zenohd.json5); a client whose router
is killed and restarted reconnects by itself (zenoh's default connect retry; its subscriptions
come back, what was published meanwhile is lost and counted by the window as ``missed``:
tests/stream/test_faults.py). What subscribes hands its samples to a queue-fed worker
(stream/worker.py).
"""

from __future__ import annotations

import json
import os
import random
import socket
import threading
import time
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
