"""Record ``robocal/**`` into MCAP and read it back in constant memory (replay: stream.replay).

One channel per key expression; JSON streams use message encoding ``json`` with a JSON schema
named ``robocal.<stream>``; model snapshots use ``robocal-model`` (the framed binary payload of
wire.codec). ``log_time`` is the receive time, ``publish_time`` the source time ``t``
(ns; the receive time when a payload has none). Chunks are zstd-compressed and indexed.

A recording is never truncated or overwritten: when the configured file exists, the recorder
writes the next free ``<stem>.<n><suffix>`` (:func:`next_free_path`); it starts a new part the
same way once a part reaches ``split_bytes`` or ``split_interval_s``. Every part opens with a
metadata record :data:`FILE_METADATA` (robocal version, part number, previous part, start time)
and the records the caller gives (the daemon: one per robot, see ``recorder_stage``). The open
chunk is written out every ``flush_interval_s``, so a killed recorder leaves a file that
:class:`RecordingReader` reads up to the last flush.
"""

from __future__ import annotations

import contextlib
import struct
import time
from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass
from datetime import UTC, datetime
from importlib.metadata import PackageNotFoundError, version
from pathlib import Path
from typing import BinaryIO

from mcap.exceptions import McapError
from mcap.reader import NonSeekingReader, SeekingReader
from mcap.records import Metadata
from mcap.stream_reader import StreamReader
from mcap.summary import Summary
from mcap.writer import Writer

from kinematics.errors import DatasetError
from wire import (
    STREAM_TYPES,
    RejectedMessageError,
    decode,
    decode_model,
    parse_json,
    split_key,
)

MODEL_ENCODING = "robocal-model"
#: The streams of the sources: what replay republishes unless told otherwise.
SOURCE_STREAMS = ("joints", "tracker", "temperature")
#: The metadata record each part starts with.
FILE_METADATA = "robocal.recording"
#: The uncompressed size at which a chunk is closed (bytes).
CHUNK_BYTES = 256 * 1024
#: Records larger than this end a read (a torn length field must not allocate gigabytes).
RECORD_LIMIT_BYTES = 256 * 2**20
_MAGIC = b"\x89MCAP0\r\n"
#: What reading past the end of an unfinished file raises.
_TORN = (McapError, EOFError, ValueError, struct.error, MemoryError)
try:  # a torn zstd frame
    from zstandard import ZstdError

    _TORN = (*_TORN, ZstdError)
except ImportError:  # pragma: no cover - mcap depends on zstandard
    pass


@dataclass(frozen=True)
class Recorded:
    """One recorded message: key, payload and the two times (ns)."""

    key: str
    payload: bytes
    log_time_ns: int
    publish_time_ns: int


def robocal_version() -> str:
    """The installed robocal version (``unknown`` when run from a bare checkout)."""
    try:
        return version("robocal")
    except PackageNotFoundError:
        return "unknown"


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


class _CountedFile:
    """A new file that counts the bytes written to it, so that a part's size is known without
    a ``tell()`` per message: each was a system call that let go of the interpreter lock, and
    beside the daemon's busy threads the recorder then waited to get it back (BENCHMARKS.md,
    "The stream's cost in the daemon")."""

    def __init__(self, file: BinaryIO) -> None:
        self.file, self.written = file, 0

    def write(self, data: bytes) -> int:
        n = self.file.write(data)
        self.written += n
        return n

    def tell(self) -> int:
        return self.written

    def flush(self) -> None:
        self.file.flush()


class McapRecorder:
    """A sink: ``add()`` messages, ``flush()`` finished chunks to disk, ``close()`` the file.

    ``split_bytes`` / ``split_interval_s`` (None: never) start a new part; ``metadata`` are
    ``(name, {key: value})`` records written at the start of every part. ``paths`` lists the
    parts written so far, ``path`` is the one being written.
    """

    def __init__(
        self,
        path: str | Path,
        flush_interval_s: float = 1.0,
        split_bytes: int | None = None,
        split_interval_s: float | None = None,
        metadata: Sequence[tuple[str, dict[str, str]]] = (),
    ) -> None:
        self.requested = Path(path)
        self.requested.parent.mkdir(parents=True, exist_ok=True)
        self._interval = flush_interval_s
        self._split_bytes, self._split_s = split_bytes, split_interval_s
        self._metadata = tuple(metadata)
        self.paths: list[Path] = []
        self.count = 0
        self.unflushed = 0  # messages added since the last flush (lost if the part is cut)
        self._open()

    def _open(self) -> None:
        while True:  # exclusive create: a file another start made meanwhile is never truncated
            path = next_free_path(self.requested)
            try:
                self._counted = _CountedFile(path.open("xb"))
                break
            except FileExistsError:
                continue
        self.path = path
        self._writer = Writer(self._counted, chunk_size=CHUNK_BYTES)
        self._writer.start(profile="", library=f"robocal {robocal_version()}")
        self._writer.add_metadata(
            FILE_METADATA,
            {
                "robocal_version": robocal_version(),
                "part": str(len(self.paths) + 1),
                "previous": self.paths[-1].name if self.paths else "",
                "started_utc": datetime.now(UTC).isoformat(timespec="milliseconds"),
                "split_bytes": str(self._split_bytes or ""),
                "split_interval_s": str(self._split_s or ""),
            },
        )
        for name, data in self._metadata:
            self._writer.add_metadata(name, {k: str(v) for k, v in data.items()})
        self.paths.append(path)
        self._channels: dict[str, int] = {}
        self._schemas: dict[str, int] = {}
        self._opened = self._last_flush = time.monotonic()
        self._writer.flush()  # header and metadata on disk at once

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
                    schema = f'{{"title": "robocal.{stream}", "type": "object"}}'.encode()
                    self._schemas[stream] = self._writer.register_schema(
                        f"robocal.{stream}", "jsonschema", schema
                    )
                schema_id, encoding = self._schemas[stream], "json"
            self._channels[key] = self._writer.register_channel(key, encoding, schema_id)
        return self._channels[key]

    def add(self, key: str, payload: bytes, log_time_ns: int | None = None) -> None:
        """Record one message received now (or at ``log_time_ns``)."""
        log_ns = time.time_ns() if log_time_ns is None else log_time_ns
        pub_ns = source_time_ns(key, payload)
        if self._split_due():  # a part is never left empty: the message that is due opens it
            self._finish()
            self._open()
        self._writer.add_message(
            self._channel(key),
            log_time=log_ns,
            data=payload,
            publish_time=log_ns if pub_ns is None else pub_ns,
            sequence=self.count,
        )
        self.count += 1
        self.unflushed += 1
        self.maybe_flush()

    def _split_due(self) -> bool:
        return (self._split_bytes is not None and self._counted.written >= self._split_bytes) or (
            self._split_s is not None and time.monotonic() - self._opened >= self._split_s
        )

    def maybe_flush(self) -> None:
        """Flush when ``flush_interval_s`` has passed since the last flush."""
        if time.monotonic() - self._last_flush >= self._interval:
            self.flush()

    def flush(self) -> None:
        """Finish the open chunk and write it out (readable after a crash)."""
        self._writer.flush()
        self._last_flush, self.unflushed = time.monotonic(), 0

    def _finish(self) -> None:
        if not self._counted.file.closed:
            self._writer.finish()
            self._counted.file.close()

    def close(self) -> None:
        """Write the summary and footer and close the file."""
        self._finish()

    def abandon(self) -> int:
        """Close the part as it is, without the footer a full disk cannot take: it stays
        readable up to its last flushed chunk (:class:`RecordingReader`). The messages added
        since that flush are lost: their count."""
        with contextlib.suppress(OSError):
            self._counted.file.close()
        lost, self.unflushed = self.unflushed, 0
        return lost

    def reopen(self) -> None:
        """Start a new part after :meth:`abandon`; a part that cannot be started is removed
        (``OSError`` while the disk is still full)."""
        try:
            self._open()
        except OSError:
            if self.path not in self.paths:  # created, never started: not a recording
                with contextlib.suppress(OSError):
                    self._counted.file.close()
                    self.path.unlink()
            raise


class RecordingReader:
    """One MCAP file read in constant memory, finished or not.

    A finished file is read through its chunk index, in log-time order, skipping the chunks
    outside the asked topics and times. An unfinished one (the recorder was killed) is read
    front to back up to its last complete chunk: messages in the order they were received,
    ``truncated`` set once its end is reached. ``position`` is the byte offset read so far.
    """

    def __init__(self, path: str | Path) -> None:
        self.path = Path(path)
        if not self.path.is_file():
            raise DatasetError(f"{self.path}: no such recording")
        self.size = self.path.stat().st_size
        with self.path.open("rb") as f:
            if f.read(len(_MAGIC)) != _MAGIC:
                raise DatasetError(f"{self.path}: not an MCAP file (no MCAP magic at the start)")
        self.summary = self._read_summary()
        self.position = 0
        self.truncated = False

    @property
    def finished(self) -> bool:
        """Whether the file has its summary and footer (the recorder closed it)."""
        return self.summary is not None

    def _read_summary(self) -> Summary | None:
        with self.path.open("rb") as f:
            try:
                return SeekingReader(f, record_size_limit=RECORD_LIMIT_BYTES).get_summary()
            except (*_TORN, OSError):  # no footer (OSError: shorter than one), read front to back
                return None

    def metadata(self) -> list[tuple[str, dict[str, str]]]:
        """The metadata records ``(name, data)``, in file order."""
        out: list[tuple[str, dict[str, str]]] = []
        with self.path.open("rb") as f:
            if self.summary is not None:
                records = SeekingReader(f, record_size_limit=RECORD_LIMIT_BYTES).iter_metadata()
            else:
                stream = StreamReader(f, emit_chunks=True, record_size_limit=RECORD_LIMIT_BYTES)
                records = stream.records
            with contextlib.suppress(*_TORN):  # an unfinished file: the records before its end
                for r in records:
                    if isinstance(r, Metadata):
                        out.append((r.name, dict(r.metadata)))
        return out

    def start_ns(self) -> int | None:
        """The log time of the first message (ns), None when there is none."""
        stats = self.summary.statistics if self.summary is not None else None
        if stats is not None and stats.message_count:
            return stats.message_start_time
        return next((r.log_time_ns for r in self.messages()), None)

    def messages(
        self,
        topics: Callable[[str], bool] | None = None,
        start_ns: int | None = None,
        end_ns: int | None = None,
    ) -> Iterator[Recorded]:
        """The messages whose key passes ``topics`` and whose log time is in
        ``[start_ns, end_ns)`` (see the class for the order)."""
        with self.path.open("rb") as f:
            if self.summary is not None and self.summary.chunk_indexes:
                wanted = [c.topic for c in self.summary.channels.values()]
                wanted = [t for t in wanted if topics is None or topics(t)]
                if not wanted:
                    self.position = self.size
                    return
                reader = SeekingReader(f, record_size_limit=RECORD_LIMIT_BYTES)
                found = reader.iter_messages(
                    wanted, starting_at=start_ns, ending_before=end_ns, log_time_order=True
                )
            else:
                reader = NonSeekingReader(f, record_size_limit=RECORD_LIMIT_BYTES)
                found = reader.iter_messages(
                    None, starting_at=start_ns, ending_before=end_ns, log_time_order=False
                )
            try:
                for _, channel, msg in found:
                    if topics is not None and not topics(channel.topic):
                        continue
                    self.position = f.tell()
                    yield Recorded(channel.topic, msg.data, msg.log_time, msg.publish_time)
            except _TORN:
                self.truncated = True
            self.position = self.size


def read_mcap(path: str | Path) -> Iterator[Recorded]:
    """Every message of a recording in constant memory (see :class:`RecordingReader`)."""
    return RecordingReader(path).messages()


def recorded_samples(path: str | Path, robot: str | None = None) -> Iterator[tuple[str, object]]:
    """Offline replay: ``(key, decoded source sample)`` in log-time order; bad ones skipped."""
    for rec in read_mcap(path):
        try:
            _, rob, stream = split_key(rec.key)
            if stream in SOURCE_STREAMS and robot in (None, rob):
                yield rec.key, decode(rec.payload, STREAM_TYPES[stream])
        except RejectedMessageError:
            continue
