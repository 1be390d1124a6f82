"""Record ``robocal/**`` into MCAP and replay it (to the bus, or offline into the window).

One channel per key expression; JSON streams use message encoding ``json`` with a JSON schema
named ``robocal.<stream>``; model snapshots use ``robocal-model`` (the framed binary payload of
stream.messages). ``log_time`` is the receive time, ``publish_time`` the source time ``t``
(ns; the receive time when a payload has none). Chunks are zstd-compressed and indexed; the
recorder finishes the open chunk every ``flush_interval_s`` so a killed recorder leaves a file
:func:`read_mcap` can read up to the last flush. A recording is never truncated or overwritten:
when the configured file exists, the recorder writes the next free ``<stem>.<n><suffix>``
(:func:`next_free_path`), one file per start.
"""

from __future__ import annotations

import json
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path

import zenoh
from mcap.exceptions import McapError
from mcap.reader import NonSeekingReader
from mcap.writer import Writer

from kinematics.errors import DatasetError
from stream.bus import BusConfig, open_session, publisher
from stream.messages import (
    STREAM_TYPES,
    RejectedMessageError,
    decode,
    decode_model,
    parse_json,
    split_key,
)

MODEL_ENCODING = "robocal-model"


@dataclass(frozen=True)
class Recorded:
    """One recorded message: key, payload and the two times (ns)."""

    key: str
    payload: bytes
    log_time_ns: int
    publish_time_ns: int


def source_time_ns(key: str, payload: bytes) -> int | None:
    """The source time ``t`` of a payload in ns, or None when it has none or is malformed."""
    try:
        stream = split_key(key)[2]
        t = decode_model(payload)[0].t if stream == "model" else parse_json(payload).get("t")
        ns = int(float(t) * 1e9) if t is not None else None
    except (RejectedMessageError, ValueError, TypeError, AttributeError, OverflowError):
        return None
    return ns if ns is not None and 0 <= ns < 2**63 else None


def next_free_path(path: str | Path) -> Path:
    """``path`` when no file is there, else the first free ``<stem>.<n><suffix>`` (n >= 1)."""
    path = Path(path)
    n = 0
    candidate = path
    while candidate.exists():
        n += 1
        candidate = path.with_name(f"{path.stem}.{n}{path.suffix}")
    return candidate


class McapRecorder:
    """A sink: ``add()`` messages, ``flush()`` finished chunks to disk, ``close()`` the file."""

    def __init__(self, path: str | Path, flush_interval_s: float = 1.0) -> None:
        self.requested = Path(path)
        self.requested.parent.mkdir(parents=True, exist_ok=True)
        while True:  # exclusive create: a file another start made meanwhile is never truncated
            self.path = next_free_path(self.requested)
            try:
                self._file = self.path.open("xb")
                break
            except FileExistsError:
                continue
        self._writer = Writer(self._file, chunk_size=256 * 1024)
        self._writer.start(profile="", library="robocal")
        self._channels: dict[str, int] = {}
        self._schemas: dict[str, int] = {}
        self._interval = flush_interval_s
        self._last_flush = time.monotonic()
        self.count = 0

    def _channel(self, key: str) -> int:
        if key not in self._channels:
            try:
                stream = split_key(key)[2]
            except RejectedMessageError:
                stream = "unknown"
            if stream == "model":
                schema_id, encoding = 0, MODEL_ENCODING
            else:
                if stream not in self._schemas:
                    schema = {"title": f"robocal.{stream}", "type": "object"}
                    self._schemas[stream] = self._writer.register_schema(
                        f"robocal.{stream}", "jsonschema", json.dumps(schema).encode()
                    )
                schema_id, encoding = self._schemas[stream], "json"
            self._channels[key] = self._writer.register_channel(key, encoding, schema_id)
        return self._channels[key]

    def add(self, key: str, payload: bytes, log_time_ns: int | None = None) -> None:
        """Record one message received now (or at ``log_time_ns``)."""
        log_ns = time.time_ns() if log_time_ns is None else log_time_ns
        pub_ns = source_time_ns(key, payload)
        self._writer.add_message(
            self._channel(key),
            log_time=log_ns,
            data=payload,
            publish_time=log_ns if pub_ns is None else pub_ns,
            sequence=self.count,
        )
        self.count += 1
        self.maybe_flush()

    def maybe_flush(self) -> None:
        """Flush when ``flush_interval_s`` has passed since the last flush."""
        if time.monotonic() - self._last_flush >= self._interval:
            self.flush()

    def flush(self) -> None:
        """Finish the open chunk and write it out (readable after a crash)."""
        self._writer.flush()
        self._last_flush = time.monotonic()

    def close(self) -> None:
        """Write the summary and footer and close the file."""
        if not self._file.closed:
            self._writer.finish()
            self._file.close()


def read_mcap(path: str | Path) -> Iterator[Recorded]:
    """Messages of a recording in log-time order; a truncated file yields what is complete."""
    path = Path(path)
    if not path.exists():
        raise DatasetError(f"{path}: no such recording")
    out: list[Recorded] = []
    with path.open("rb") as f:
        reader = NonSeekingReader(f, validate_crcs=False)
        try:
            for _, channel, msg in reader.iter_messages(log_time_order=False):
                out.append(Recorded(channel.topic, msg.data, msg.log_time, msg.publish_time))
        except (McapError, EOFError, ValueError) as exc:
            if not out:
                raise DatasetError(f"{path}: not a readable MCAP file: {exc}") from None
    out.sort(key=lambda r: r.log_time_ns)
    yield from out


def replay_to_bus(
    path: str | Path,
    session: zenoh.Session,
    speed: float | None = None,
    streams: tuple[str, ...] = ("joints", "tracker", "temperature"),
    on_message: Callable[[Recorded], None] | None = None,
) -> int:
    """Republish the recorded ``streams`` in log-time order at ``speed`` x (None: at once)."""
    pubs: dict[str, zenoh.Publisher] = {}
    start_wall = start_log = None
    n = 0
    for rec in read_mcap(path):
        try:
            if split_key(rec.key)[2] not in streams:
                continue
        except RejectedMessageError:
            continue
        if speed is not None:
            if start_wall is None:
                start_wall, start_log = time.monotonic(), rec.log_time_ns
            wait = start_wall + (rec.log_time_ns - start_log) / 1e9 / speed - time.monotonic()
            if wait > 0:
                time.sleep(wait)
        if rec.key not in pubs:
            pubs[rec.key] = publisher(session, rec.key)
        pubs[rec.key].put(rec.payload)
        n += 1
        if on_message is not None:
            on_message(rec)
    for pub in pubs.values():
        pub.undeclare()
    return n


def replay_file(
    path: str | Path, bus: BusConfig, speed: float | None = None, settle_s: float = 1.0
) -> int:
    """Open a session from ``bus``, wait ``settle_s`` for links, replay ``path``; the count."""
    if not Path(path).exists():
        raise DatasetError(f"{path}: no such recording")
    session = open_session(bus)
    try:
        time.sleep(settle_s)
        return replay_to_bus(path, session, speed)
    finally:
        session.close()


def recorded_samples(path: str | Path, robot: str | None = None) -> Iterator[tuple[str, object]]:
    """Offline replay: ``(key, decoded source sample)`` in log-time order; bad ones skipped."""
    for rec in read_mcap(path):
        try:
            _, rob, stream = split_key(rec.key)
            if stream in ("joints", "tracker", "temperature") and robot in (None, rob):
                yield rec.key, decode(rec.payload, STREAM_TYPES[stream])
        except RejectedMessageError:
            continue
