"""The wire codec: messages as JSON with their bounds checked, model framing, drop counts.

Every JSON payload is an object with ``schema`` (``robocal.<stream>``) and ``version``
(:data:`~wire.messages.VERSION`) beside the dataclass fields. A payload is refused before it
is parsed when it is too large or too deeply nested; every refusal is a
:class:`~wire.messages.RejectedMessageError` whose ``reason`` the stage's
:class:`DropCounter` counts it under.

Model snapshots are binary: ``u64 little-endian header length | header JSON | safetensors``,
where the header is a :class:`~wire.messages.ModelHeader` (JSON with ``schema``/``version``)
and the safetensors bytes come from ``learner.snapshot.snapshot_to_bytes`` (weights plus their
own JSON metadata; never pickle). :func:`encode_model` / :func:`decode_model` frame and unframe.

>>> from wire.messages import TemperatureSample
>>> s = TemperatureSample(seq=0, t=1.0, names=("ambient",), values=(21.5,))
>>> decode(encode(s), TemperatureSample) == s
True
"""

from __future__ import annotations

import functools
import json
import re
import struct
from collections import Counter
from dataclasses import MISSING, asdict, fields
from typing import Any, TypeVar

from wire.messages import (
    MAX_DEPTH,
    MAX_PAYLOAD_BYTES,
    VERSION,
    DataPoint,
    Diagnostics,
    ModelHeader,
    RejectedMessageError,
)

__all__ = [
    "DropCounter",
    "decode",
    "decode_model",
    "encode",
    "encode_model",
    "from_dict",
    "json_depth",
    "parse_json",
    "to_dict",
]

Message = TypeVar("Message")


def to_dict(msg: Any) -> dict[str, Any]:
    """The JSON-ready dict of a message, with ``schema`` and ``version``."""
    return {"schema": msg.SCHEMA, "version": VERSION, **asdict(msg)}


def encode(msg: Any) -> bytes:
    """Compact UTF-8 JSON of a message: :func:`to_dict`'s JSON, written without its deep copy
    (a joint sample in 9 µs instead of 21-25: the sources and the window encode every sample)."""
    head = {"schema": msg.SCHEMA, "version": VERSION, **_fields_of(msg)}
    return json.dumps(head, separators=(",", ":"), allow_nan=True, default=_fields_of).encode()


def _fields_of(msg: Any) -> dict[str, Any]:
    """A message's fields by name, unconverted: JSON writes tuples as lists, and a message
    nested in one (a batch's points) comes back here as its ``default``."""
    try:
        names = _field_names(type(msg))[0]
    except TypeError:
        raise TypeError(f"{type(msg).__name__} is not JSON serializable") from None
    return {name: getattr(msg, name) for name in names}


def decode(payload: bytes | str, cls: type[Message]) -> Message:
    """Parse and validate a payload as ``cls``; raise RejectedMessageError (reason)."""
    return from_dict(parse_json(payload), cls)


_BRACKETS = re.compile(rb"[\[\]{}]")
_STRINGS = re.compile(rb'"(?:[^"\\]|\\.)*"')


def parse_json(payload: bytes | str, max_bytes: int = MAX_PAYLOAD_BYTES) -> Any:
    """``json.loads`` after the size and nesting-depth limits (``too_large``, ``too_deep``)."""
    data = payload.encode() if isinstance(payload, str) else bytes(payload)
    if len(data) > max_bytes:
        raise RejectedMessageError("too_large", f"{len(data)} bytes > limit {max_bytes}")
    # No deeper than its opening brackets: a sample's few are counted in C, not scanned.
    if data.count(b"[") + data.count(b"{") > MAX_DEPTH and json_depth(data) > MAX_DEPTH:
        raise RejectedMessageError("too_deep", f"JSON nested deeper than {MAX_DEPTH}")
    try:
        return json.loads(data)
    except (ValueError, UnicodeDecodeError, RecursionError) as exc:
        raise RejectedMessageError("malformed", f"not JSON ({exc.__class__.__name__})") from None


def json_depth(data: bytes, stop_at: int = MAX_DEPTH) -> int:
    """Deepest bracket nesting of JSON text (brackets in strings do not count), linear; stops
    counting past ``stop_at``.

    >>> json_depth(b'{"a": [1, [2]], "b": "[[["}')
    3
    """
    depth = deepest = 0
    for m in _BRACKETS.finditer(_STRINGS.sub(b'""', data)):
        if m.group() in (b"[", b"{"):
            depth += 1
            deepest = max(deepest, depth)
            if deepest > stop_at:
                break
        else:
            depth -= 1
    return deepest


def from_dict(raw: Any, cls: type[Message]) -> Message:
    """Validate a parsed JSON object as ``cls``."""
    if not isinstance(raw, dict):
        raise RejectedMessageError("malformed", f"expected a JSON object, got {type(raw).__name__}")
    if raw.get("schema") != cls.SCHEMA:
        raise RejectedMessageError(
            "schema", f"expected schema {cls.SCHEMA!r}, got {raw.get('schema')!r}"
        )
    if raw.get("version") != VERSION:
        raise RejectedMessageError(
            "version", f"expected version {VERSION}, got {raw.get('version')!r}"
        )
    names, required = _field_names(cls)
    values = {k: raw[k] for k in names if k in raw}
    missing = required - values.keys()
    if missing:
        raise RejectedMessageError("malformed", f"{cls.SCHEMA}: missing field(s) {sorted(missing)}")
    try:
        msg = cls(**{k: _freeze(k, v) for k, v in values.items()})
        msg.check()
    except (TypeError, ValueError, AttributeError) as exc:  # wrong JSON types in fields
        raise RejectedMessageError("malformed", f"{cls.SCHEMA}: {exc}") from None
    return msg


@functools.cache
def _field_names(cls: type) -> tuple[tuple[str, ...], frozenset[str]]:
    """All field names of a message class, in order, and the required ones."""
    all_ = tuple(f.name for f in fields(cls))
    required = frozenset(
        f.name for f in fields(cls) if f.default is MISSING and f.default_factory is MISSING
    )
    return all_, required


def _freeze(name: str, value: Any) -> Any:
    if name == "points":
        if not isinstance(value, list):
            raise ValueError("points must be a list")
        if not all(isinstance(p, dict) for p in value):
            raise ValueError("points must be JSON objects")
        return tuple(
            from_dict({**p, "schema": DataPoint.SCHEMA, "version": VERSION}, DataPoint)
            for p in value
        )
    if isinstance(value, list):
        return tuple(value)
    return value


def encode_model(header: ModelHeader, snapshot: bytes) -> bytes:
    """Frame a snapshot: ``u64 LE header length | header JSON | safetensors bytes``."""
    head = encode(header)
    return struct.pack("<Q", len(head)) + head + snapshot


def decode_model(payload: bytes) -> tuple[ModelHeader, bytes]:
    """Unframe a model payload into its header and the safetensors bytes."""
    if len(payload) < 8:
        raise RejectedMessageError(
            "malformed", f"model payload of {len(payload)} bytes is too short"
        )
    (n,) = struct.unpack("<Q", payload[:8])
    if n > min(len(payload) - 8, MAX_PAYLOAD_BYTES):
        raise RejectedMessageError("malformed", f"model header length {n} beyond payload")
    return decode(payload[8 : 8 + n], ModelHeader), bytes(payload[8 + n :])


class DropCounter:
    """Counts accepted messages and drops by reason; the stage's diagnostics source."""

    def __init__(self, stage: str) -> None:
        self.stage = stage
        self.accepted = 0
        self.dropped: Counter[str] = Counter()
        self.refused: dict[str, str] = {}

    def drop(self, reason: str, n: int = 1) -> None:
        self.dropped[reason] += n

    def accept(self, n: int = 1) -> None:
        self.accepted += n

    def refuse(self, kind: str, reason: str, detail: str) -> bool:
        """Count a refusal (e.g. of a model) under ``reason`` and keep its ``detail`` as the
        last of its ``kind``; True the first time ``kind`` is refused (log it then, once)."""
        self.drop(reason)
        first = kind not in self.refused
        self.refused[kind] = detail
        return first

    def diagnostics(self, t: float = 0.0) -> Diagnostics:
        return Diagnostics(
            stage=self.stage,
            accepted=self.accepted,
            dropped=dict(self.dropped),
            t=t,
            refused=dict(self.refused),
        )
