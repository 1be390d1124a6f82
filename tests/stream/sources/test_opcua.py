"""The OPC UA source against a real asyncua server on loopback: temperatures under the
description's channel names, a bad sensor status counted, and a server restart on the same
port (the source reconnects, samples resume, the periods without one are counted)."""

from __future__ import annotations

import io
import time

import pytest

from kinematics.errors import ConfigError
from stream.log import JsonLogger
from stream.sources.build import SourceThread
from stream.sources.config import OpcUaSourceConfig
from stream.sources.opcua import OpcUaSource
from tests.stream.conftest import wait_for
from tests.stream.sources.conftest import CELL, ROBOT

pytestmark = pytest.mark.integration


def start(session, server, period_s: float = 0.1) -> SourceThread:
    cfg = OpcUaSourceConfig(
        url=server.url, nodes=server.node_ids, period_s=period_s, reconnect_s=0.2, timeout_s=2.0
    )
    source = OpcUaSource(session, CELL, ROBOT, cfg, declared=("base", "j1_gear", "wrist"))
    return SourceThread(source, JsonLogger(stream=io.StringIO())).start()


def test_temperatures_and_a_failed_sensor(bus, opcua_server):
    session, collector = bus
    opcua_server.write("base", 24.5)
    src = start(session, opcua_server)
    try:
        first = collector.wait("temperature", 3)
        opcua_server.write("j1_gear", 0.0, good=False)  # the PLC reports a sensor failure
        assert wait_for(lambda: src.source.counter.dropped["bad_value"] >= 2)
        opcua_server.write("j1_gear", 31.0)
        n = len(collector.raw["temperature"])
        after = collector.wait("temperature", n + 2)
    finally:
        src.close()
    assert first[0].names == ("base", "j1_gear")
    assert first[0].values == (24.5, 21.0)
    assert after[-1].values == (24.5, 31.0)
    assert abs(after[-1].t - time.time()) < 60  # the server's source timestamps (s since 1970)
    seqs = [s.seq for s in collector.decoded("temperature")]
    assert seqs == list(range(len(seqs)))


def test_server_restart_reconnects_and_counts_lost_periods(bus, opcua_server):
    session, collector = bus
    src = start(session, opcua_server)
    try:
        assert collector.wait("temperature", 3)
        opcua_server.stop()
        time.sleep(1.0)  # ten periods without a server
        before = len(collector.raw["temperature"])
        lost = src.source.counter.dropped["disconnected"]
        opcua_server.start()  # same port, same nodes
        resumed = collector.wait("temperature", before + 3)
    finally:
        src.close()
    assert len(resumed) >= before + 3
    assert lost >= 3  # each period without a reading is counted
    assert src.source.connects >= 2
    assert "connection" in src.source.counter.refused


def test_channels_must_be_the_descriptions():
    cfg = OpcUaSourceConfig(url="opc.tcp://127.0.0.1:4840", nodes={"elbow": "ns=2;s=X"})
    with pytest.raises(ConfigError, match=r"channel\(s\) \['elbow'\]"):
        OpcUaSource(None, CELL, ROBOT, cfg, declared=("base",))
