"""Replay recordings onto the bus: streamed from the files in constant memory (``robocal replay``).

The parts of a recording are given in order; each is read by
:class:`~stream.mcap_io.RecordingReader` (a killed recorder's file up to its last complete chunk).
``topics`` are stream names (``joints``) or full keys; ``start_s``/``end_s`` are seconds after
the first message of the first part. With ``loops`` > 1 (None: until stopped) pass ``k`` is
republished shifted by ``k`` times the recording's span in ``t`` (source time, span + 1 s) and
by ``k`` times (largest ``seq`` + 1) per key, so that a running window takes it as new data.
"""

from __future__ import annotations

import json
import math
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field, replace
from pathlib import Path

import zenoh

from kinematics.errors import ConfigError
from stream.bus import BusConfig, open_session, publisher, wait_matched
from stream.mcap_io import SOURCE_STREAMS, Recorded, RecordingReader
from wire import RejectedMessageError, split_key


@dataclass(frozen=True, kw_only=True)
class ReplayOptions:
    """What to republish and how fast (``speed`` x real time; None: as fast as possible), once
    each key has a subscriber or ``wait_subscribers_s`` (s) have passed since the start."""

    speed: float | None = None
    topics: tuple[str, ...] = SOURCE_STREAMS
    start_s: float | None = None
    end_s: float | None = None
    loops: int | None = 1
    wait_subscribers_s: float = 10.0

    def __post_init__(self) -> None:
        if self.speed is not None and not (math.isfinite(self.speed) and self.speed > 0):
            raise ConfigError(f"replay speed must be > 0, got {self.speed}")
        if not (math.isfinite(self.wait_subscribers_s) and self.wait_subscribers_s >= 0):
            raise ConfigError(
                f"replay wait for subscribers must be >= 0 s, got {self.wait_subscribers_s}"
            )
        if not self.topics:
            raise ConfigError("replay needs at least one topic")
        for name, value in (("start", self.start_s), ("end", self.end_s)):
            if value is not None and not (math.isfinite(value) and value >= 0):
                raise ConfigError(f"replay {name} must be >= 0 s, got {value}")
        if self.start_s is not None and self.end_s is not None and self.end_s <= self.start_s:
            raise ConfigError(f"replay end ({self.end_s} s) must be after start ({self.start_s} s)")
        if self.loops is not None and self.loops < 1:
            raise ConfigError(f"replay loops must be >= 1 (None: forever), got {self.loops}")

    def wants(self, key: str) -> bool:
        """Whether the channel ``key`` is replayed (a stream name or the full key matches)."""
        if key in self.topics:
            return True
        try:
            return split_key(key)[2] in self.topics
        except RejectedMessageError:
            return False


@dataclass
class ReplayResult:
    """What a replay published: messages, passes, per stream, the files cut short, the keys
    nobody subscribed to in time, and whether Ctrl-C stopped it."""

    published: int = 0
    passes: int = 0
    by_stream: dict[str, int] = field(default_factory=dict)
    truncated: list[str] = field(default_factory=list)
    unheard: list[str] = field(default_factory=list)
    stopped: bool = False


def _shifted(payload: bytes, dt_s: float, dseq: int) -> bytes:
    """``payload`` with ``t`` moved by ``dt_s`` and ``seq`` by ``dseq`` (as is when not JSON)."""
    try:
        data = json.loads(payload)
    except (ValueError, RecursionError):
        return payload
    if not isinstance(data, dict):
        return payload
    if isinstance(data.get("t"), int | float) and not isinstance(data.get("t"), bool):
        data["t"] += dt_s
    if isinstance(data.get("seq"), int) and not isinstance(data.get("seq"), bool):
        data["seq"] += dseq
    return json.dumps(data, separators=(",", ":")).encode()


def replay_to_bus(
    paths: str | Path | Sequence[str | Path],
    session: zenoh.Session,
    speed: float | None = None,
    options: ReplayOptions | None = None,
    on_progress: Callable[[int, int], None] | None = None,
    on_message: Callable[[Recorded], None] | None = None,
) -> ReplayResult:
    """Republish the recording ``paths`` (its parts, in order) as ``options`` say (``speed``
    overrides theirs). ``on_progress(bytes_read, pass)`` follows the files."""
    paths = [Path(paths)] if isinstance(paths, str | Path) else [Path(p) for p in paths]
    opts = options or ReplayOptions()
    if speed is not None:
        opts = replace(opts, speed=speed)
    readers = [RecordingReader(p) for p in paths]  # every file checked before anything is sent
    first = next((ns for ns in (r.start_ns() for r in readers) if ns is not None), 0)
    start_ns = None if opts.start_s is None else first + int(opts.start_s * 1e9)
    end_ns = None if opts.end_s is None else first + int(opts.end_s * 1e9)
    pubs: dict[str, zenoh.Publisher] = {}
    result = ReplayResult()
    heard_by = time.monotonic() + opts.wait_subscribers_s
    t_range = [math.inf, -math.inf]
    max_seq: dict[str, int] = {}
    try:
        while opts.loops is None or result.passes < opts.loops:
            k = result.passes
            span = t_range[1] - t_range[0] + 1.0 if t_range[1] >= t_range[0] else 0.0
            done_before, wall0, log0 = 0, None, None
            for reader in (RecordingReader(p) for p in paths):
                for rec in reader.messages(opts.wants, start_ns, end_ns):
                    if rec.key not in pubs:  # a subscriber still starting would miss its start
                        pubs[rec.key] = publisher(session, rec.key)
                        left = max(0.0, heard_by - time.monotonic())
                        result.unheard += wait_matched([pubs[rec.key]], left)
                    if opts.speed is not None:
                        if wall0 is None:
                            wall0, log0 = time.monotonic(), rec.log_time_ns
                        wait = wall0 + (rec.log_time_ns - log0) / 1e9 / opts.speed
                        wait -= time.monotonic()
                        if wait > 0:
                            time.sleep(wait)
                    payload = rec.payload
                    if k == 0 and opts.loops != 1:
                        _track(rec, t_range, max_seq)
                    else:
                        payload = _shifted(payload, k * span, k * (max_seq.get(rec.key, -1) + 1))
                    pubs[rec.key].put(payload)
                    stream = rec.key.rsplit("/", 1)[-1]
                    result.by_stream[stream] = result.by_stream.get(stream, 0) + 1
                    result.published += 1
                    if on_message is not None:
                        on_message(rec)
                    if on_progress is not None:
                        on_progress(done_before + reader.position, k)
                done_before += reader.size
                if on_progress is not None:
                    on_progress(done_before, k)
                if reader.truncated and k == 0:
                    result.truncated.append(str(reader.path))
            result.passes += 1
    except KeyboardInterrupt:  # how a replay without an end (loops=None) is ended
        result.stopped = True
    finally:
        for pub in pubs.values():
            pub.undeclare()
    return result


def _track(rec: Recorded, t_range: list[float], max_seq: dict[str, int]) -> None:
    """Widen the source-time range and the per-key largest ``seq`` with ``rec`` (first pass)."""
    t = rec.publish_time_ns / 1e9
    t_range[0], t_range[1] = min(t_range[0], t), max(t_range[1], t)
    try:
        seq = json.loads(rec.payload).get("seq")
    except (ValueError, RecursionError, AttributeError):
        return
    if isinstance(seq, int) and not isinstance(seq, bool):
        max_seq[rec.key] = max(max_seq.get(rec.key, -1), seq)


def check_recordings(paths: Sequence[str | Path]) -> int:
    """Their total size (bytes); DatasetError in one line for a missing or non-MCAP file."""
    return sum(RecordingReader(p).size for p in paths)


def replay_files(
    paths: Sequence[str | Path],
    bus: BusConfig,
    options: ReplayOptions | None = None,
    on_progress: Callable[[int, int], None] | None = None,
) -> ReplayResult:
    """Open a session from ``bus`` and replay ``paths`` (each key once it has a subscriber)."""
    check_recordings(paths)  # a missing or foreign file fails before the session opens
    session = open_session(bus)
    try:
        return replay_to_bus(paths, session, options=options, on_progress=on_progress)
    finally:
        session.close()
