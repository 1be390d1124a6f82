"""OPC UA temperatures (a DAQ or PLC) with ``asyncua``: one node per temperature channel.

Every ``period_s`` the source reads the configured nodes in one request and publishes a
``TemperatureSample`` with the channel names of the config (the description's names) and the
values (°C) at the nodes' source timestamp (else the server's, else the local clock, s since
1970). When the server drops or restarts, the source reconnects every ``reconnect_s``; each
period without a sample is counted as undelivered (``disconnected``), as is a reading with a bad
status or a value that is not a number (``bad_value``).
"""

from __future__ import annotations

import asyncio
import contextlib
import math
import time
from datetime import datetime

import zenoh
from asyncua import Client, ua

from kinematics.errors import ConfigError
from stream.sources._base import Source
from stream.sources.config import OpcUaSourceConfig
from wire import TemperatureSample

#: What a dropped or restarting server raises on a request.
CONNECTION_ERRORS = (OSError, EOFError, TimeoutError, asyncio.TimeoutError, ua.UaError)


def check_channels(cfg: OpcUaSourceConfig, declared: tuple[str, ...]) -> None:
    """ConfigError unless the channels are the description's (when it declares any)."""
    unknown = [c for c, _ in cfg.nodes if declared and c not in (*declared, "ambient")]
    if unknown:
        raise ConfigError(
            f"sources.nodes: channel(s) {unknown} are not the description's {list(declared)}"
        )


def _seconds(stamp: datetime | None) -> float | None:
    return None if stamp is None else stamp.timestamp()


class OpcUaSource(Source):
    """Temperatures read from an OPC UA server (module docstring)."""

    kind = "opcua"

    def __init__(
        self,
        session: zenoh.Session,
        cell: str,
        robot: str,
        cfg: OpcUaSourceConfig,
        declared: tuple[str, ...] = (),
    ) -> None:
        check_channels(cfg, declared)
        super().__init__(session, cell, robot)
        self.cfg = cfg
        self.names = tuple(c for c, _ in cfg.nodes)
        self.connects = 0
        self._seq = 0

    def run(self) -> None:
        asyncio.run(self._main())

    async def _sleep_until(self, deadline: float) -> None:
        while self.running and time.monotonic() < deadline:
            await asyncio.sleep(min(0.05, max(deadline - time.monotonic(), 0.0)))

    async def _main(self) -> None:
        cfg = self.cfg
        client: Client | None = None
        next_tick = next_connect = time.monotonic()
        try:
            while self.running:
                if client is None and time.monotonic() >= next_connect:
                    client = await self._connect()
                    next_connect = time.monotonic() + cfg.reconnect_s
                if client is None:
                    self.undelivered("disconnected")
                else:
                    try:
                        await self._poll(client)
                    except CONNECTION_ERRORS as exc:
                        self._lost(str(exc) or type(exc).__name__)
                        self.undelivered("disconnected")
                        await self._close(client)
                        client = None
                next_tick += cfg.period_s
                behind = int((time.monotonic() - next_tick) // cfg.period_s)
                if behind > 0:  # a request took several periods: each one is a lost sample
                    self.undelivered("disconnected", behind)
                    next_tick += behind * cfg.period_s
                await self._sleep_until(next_tick)
        finally:
            if client is not None:
                await self._close(client)

    async def _connect(self) -> Client | None:
        client = Client(url=self.cfg.url, timeout=self.cfg.timeout_s)
        try:
            await asyncio.wait_for(client.connect(), self.cfg.timeout_s)
        except CONNECTION_ERRORS as exc:
            self._lost(str(exc) or type(exc).__name__)
            await self._close(client)
            return None
        self.nodes = [client.get_node(node_id) for _, node_id in self.cfg.nodes]
        self.connects += 1
        return client

    def _lost(self, detail: str) -> None:
        with self._lock:
            self.counter.refused["connection"] = f"{self.cfg.url}: {detail}"[:300]

    async def _close(self, client: Client) -> None:
        with contextlib.suppress(Exception):  # the connection is gone already
            await asyncio.wait_for(client.disconnect(), self.cfg.timeout_s)

    async def _poll(self, client: Client) -> None:
        values = await asyncio.wait_for(client.read_attributes(self.nodes), self.cfg.timeout_s)
        sample = self.sample(values)
        if sample is not None:
            self.publish(sample)

    def sample(self, values: list[ua.DataValue]) -> TemperatureSample | None:
        """The temperature sample of one reading, or None (counted ``bad_value``)."""
        out, stamps = [], []
        for dv in values:
            v = dv.Value.Value if dv.Value is not None else None
            good = dv.StatusCode is None or dv.StatusCode.is_good()
            if not good or isinstance(v, bool) or not isinstance(v, int | float):
                self.undelivered("bad_value")
                return None
            out.append(float(v))
            stamps.append(_seconds(dv.SourceTimestamp) or _seconds(dv.ServerTimestamp))
        known = [s for s in stamps if s is not None and math.isfinite(s)]
        t = max(known) if known else time.time()
        self._seq += 1
        return TemperatureSample(seq=self._seq - 1, t=t, names=self.names, values=tuple(out))
