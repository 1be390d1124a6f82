"""The line's Zenoh router, run by robocal itself: a Zenoh session in router mode.

``robocal router --config deploy/zenohd.json5`` opens it from the shipped config (mutual TLS,
access control) and keeps it until SIGTERM/SIGINT; ``zenohd -c`` the same file works too.
"""

from __future__ import annotations

import json
import os
import signal
import threading
from collections.abc import Callable
from pathlib import Path

import zenoh

from kinematics.errors import ConfigError

_TLS_FILES = ("root_ca_certificate", "listen_certificate", "listen_private_key")


def router_config(
    path: str | Path, listen: tuple[str, ...] = (), certs: str | Path | None = None
) -> zenoh.Config:
    """The router's Zenoh config from ``path``, with its listen endpoints and certificate
    folder (``ca.pem``, ``router.pem``, ``router.key``) optionally replaced; ConfigError for a
    file that is not a router config or a certificate that cannot be read."""
    try:
        zc = zenoh.Config.from_file(str(path))
    except (zenoh.ZError, OSError, ValueError) as exc:
        raise ConfigError(f"router config {str(path)!r}: {exc}") from None
    if json.loads(zc.get_json("mode")) != "router":
        raise ConfigError(f'router config {str(path)!r}: mode must be "router"')
    if listen:
        zc.insert_json5("listen/endpoints", json.dumps(list(listen)))
    if certs is not None:
        for key, name in zip(_TLS_FILES, ("ca.pem", "router.pem", "router.key"), strict=True):
            zc.insert_json5(f"transport/link/tls/{key}", json.dumps(str(Path(certs) / name)))
    for key in _TLS_FILES:
        file = json.loads(zc.get_json(f"transport/link/tls/{key}"))
        if file is not None and not os.access(file, os.R_OK):
            raise ConfigError(f"router config: {key} {file!r} cannot be read")
    return zc


def open_router(zc: zenoh.Config) -> zenoh.Session:
    """Open the router session (ConfigError when it cannot listen, e.g. a port in use)."""
    try:
        return zenoh.open(zc)
    except zenoh.ZError as exc:
        raise ConfigError(f"cannot start the router: {exc}") from None


def run_router(zc: zenoh.Config, on_start: Callable[[list[str]], None] | None = None) -> int:
    """Run the router until SIGTERM or SIGINT; 0. ``on_start(endpoints)`` once it listens."""
    stop = threading.Event()
    previous = {s: signal.signal(s, lambda *_: stop.set()) for s in (signal.SIGTERM, signal.SIGINT)}
    try:
        session = open_router(zc)
        try:
            if on_start is not None:
                on_start(json.loads(zc.get_json("listen/endpoints")))
            # Polled, not one blocking wait: SIGTERM may land on one of zenoh's threads, and a
            # main thread blocked without a timeout would then never run the handler.
            while not stop.wait(0.2):
                pass
        finally:
            session.close()
    finally:
        for sig, handler in previous.items():
            signal.signal(sig, handler)
    return 0
