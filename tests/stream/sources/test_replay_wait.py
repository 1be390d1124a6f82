"""A replayed source waits for its window: started before anything subscribes, it streams
nothing until each of its streams has a subscriber, so that a fast replay's first samples are
not lost; with nobody listening it streams after ``wait_subscribers_s`` and names the streams."""

from __future__ import annotations

import threading
import time

import pytest

from kinematics.dataset import Dataset, read_dataset, temperature_columns, write_dataset
from kinematics.description import load_description
from stream.bus import BusConfig, free_port, open_session
from stream.mcap_io import SOURCE_STREAMS
from stream.sources.config import DatasetSourceConfig
from stream.sources.dataset import dataset_source
from tests.stream.conftest import wait_subscribed
from tests.stream.sources.conftest import CELL, ROBOT, Collector
from wire import key

pytestmark = pytest.mark.integration


def test_a_replay_started_before_its_subscriber_loses_nothing(dataset_file):
    port = free_port()
    pub = open_session(BusConfig.loopback(port, listen=True))
    sub = open_session(BusConfig.loopback(port, listen=False))
    try:
        cfg = DatasetSourceConfig(
            path=str(dataset_file), speed=0, wait_subscribers_s=60, joint_rate_hz=25.0
        )
        source = dataset_source(pub, CELL, ROBOT, cfg, load_description(ROBOT))
        thread = threading.Thread(target=source.start, daemon=True)
        thread.start()
        time.sleep(1.0)  # as fast as possible, the whole file would be gone by now
        assert source.published == 0
        collector = Collector(sub)
        thread.join(60)
        assert not thread.is_alive() and source.published > 0

        def heard() -> int:
            return sum(len(collector.raw[s]) for s in SOURCE_STREAMS)

        deadline = time.monotonic() + 30
        while heard() < source.published and time.monotonic() < deadline:
            time.sleep(0.05)
        assert heard() == source.published
        assert "unheard" not in source.diagnostics()
    finally:
        sub.close()
        pub.close()


def test_a_replay_nobody_hears_streams_after_its_wait_and_says_so(dataset_file):
    session = open_session(BusConfig.loopback(free_port(), listen=True))
    try:
        cfg = DatasetSourceConfig(
            path=str(dataset_file), speed=0, wait_subscribers_s=0.3, joint_rate_hz=25.0
        )
        source = dataset_source(session, CELL, ROBOT, cfg, load_description(ROBOT))
        start = time.monotonic()
        source.start()
        assert 0.3 <= time.monotonic() - start < 10
        diag = source.diagnostics()
        assert diag["published"] > 0
        assert diag["unheard"] == [f"robocal/{CELL}/{ROBOT}/{s}" for s in SOURCE_STREAMS]
    finally:
        session.close()


def test_a_dataset_without_thermometers_waits_only_for_joints_and_tracker(dataset_file, tmp_path):
    ds = read_dataset(dataset_file)
    bare = tmp_path / "no_thermometer.parquet"
    write_dataset(Dataset(ds.table.drop(columns=temperature_columns(ds.table)), ds.meta), bare)
    port = free_port()
    pub = open_session(BusConfig.loopback(port, listen=True))
    sub = open_session(BusConfig.loopback(port, listen=False))
    try:
        heard = {
            s: sub.declare_subscriber(key(CELL, ROBOT, s), lambda _: None)
            for s in SOURCE_STREAMS
            if s != "temperature"
        }
        wait_subscribed(pub, *(key(CELL, ROBOT, s) for s in heard))
        cfg = DatasetSourceConfig(
            path=str(bare), speed=0, wait_subscribers_s=30, joint_rate_hz=25.0
        )
        source = dataset_source(pub, CELL, ROBOT, cfg, load_description(ROBOT))
        start = time.monotonic()
        source.start()
        assert time.monotonic() - start < 10  # nobody needs to hear a temperature it never sends
        assert source.published > 0 and "unheard" not in source.diagnostics()
    finally:
        sub.close()
        pub.close()
