"""Wire messages of the pipeline: key expressions, frozen dataclasses and their bounds.

The layer under ``sim_sources/`` and ``stream/`` (it depends on ``kinematics.errors`` only).
SI units (rad, m, s, °C). Source samples carry the source time ``t`` (s) and a per-source
sequence number ``seq``.

Bounds are part of the schema: a payload larger than :data:`MAX_PAYLOAD_BYTES` (``too_large``)
or nested deeper than :data:`MAX_DEPTH` (``too_deep``) is refused before it is parsed (by
:mod:`wire.codec`); ``seq`` is an int in ``0..MAX_SEQ`` and ``t`` (s) within ``±MAX_TIME_S``
(``out_of_range``); name lists are non-empty and unique. Every refusal is a
:class:`RejectedMessageError` whose ``reason`` is the counter it is dropped under.

>>> key("cell1", "ur10", "joints")
'robocal/cell1/ur10/joints'
>>> split_key("robocal/cell1/ur10/joints")
('cell1', 'ur10', 'joints')
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, fields
from typing import Any, ClassVar

from kinematics.errors import SchemaError

__all__ = [
    "JOINT_LIMIT_RAD",
    "MAX_DEPTH",
    "MAX_PAYLOAD_BYTES",
    "MAX_SEQ",
    "MAX_TIME_S",
    "POSITION_LIMIT_M",
    "QUATERNION_TOLERANCE",
    "ROOT",
    "STREAM_TYPES",
    "STREAMS",
    "TEMPERATURE_RANGE_C",
    "VERSION",
    "Batch",
    "DataPoint",
    "Diagnostics",
    "JointSample",
    "Metrics",
    "ModelHeader",
    "RejectedMessageError",
    "Stamped",
    "TemperatureSample",
    "TrackerSample",
    "check_count",
    "check_finite",
    "key",
    "split_key",
]

VERSION = 1
ROOT = "robocal"
STREAMS = (
    "joints",
    "tracker",
    "temperature",
    "points",
    "batches",
    "model",
    "metrics",
    "diagnostics",
    "compensate",
)
#: Physical plausibility ranges for validation on arrival.
TEMPERATURE_RANGE_C = (-40.0, 150.0)
POSITION_LIMIT_M = 100.0
JOINT_LIMIT_RAD = 4 * math.pi
QUATERNION_TOLERANCE = 1e-3
#: Largest JSON payload (bytes) parsed at all; a batch of 1,000 points is about 0.5 MB.
MAX_PAYLOAD_BYTES = 4_000_000
#: Deepest JSON nesting parsed (a batch is 4 deep: batch, points, point, list).
MAX_DEPTH = 8
#: Largest sequence number and model version (2**53: exact as a JSON number everywhere).
MAX_SEQ = 2**53
#: Largest |t| (s) of any sample: beyond the year 2286 is not a time.
MAX_TIME_S = 1e10


class RejectedMessageError(SchemaError):
    """A message that is dropped; ``reason`` is the counter it is counted under."""

    def __init__(self, reason: str, detail: str) -> None:
        super().__init__(f"{reason}: {detail}")
        self.reason = reason


def key(cell: str, robot: str, stream: str) -> str:
    """The key expression ``robocal/<cell>/<robot>/<stream>``."""
    if stream not in STREAMS:
        raise SchemaError(f"stream must be one of {STREAMS}, got {stream!r}")
    return f"{ROOT}/{cell}/{robot}/{stream}"


def split_key(k: str) -> tuple[str, str, str]:
    """``(cell, robot, stream)`` of a key expression made by :func:`key`."""
    parts = str(k).split("/")
    if len(parts) != 4 or parts[0] != ROOT or parts[3] not in STREAMS:
        raise RejectedMessageError(
            "bad_key", f"expected robocal/<cell>/<robot>/<stream>, got {k!r}"
        )
    return parts[1], parts[2], parts[3]


@dataclass(frozen=True, kw_only=True)
class Stamped:
    """What every source sample and data point carries: the source's sequence number ``seq``
    and the source time ``t`` (s); ``check`` bounds both."""

    seq: int
    t: float

    def check(self) -> None:
        check_count("seq", self.seq)
        _check_time(self.t)


@dataclass(frozen=True, kw_only=True)
class JointSample(Stamped):
    """Controller joint angles ``q`` (rad) and optional secondary encoders ``qs`` at time ``t``."""

    SCHEMA: ClassVar[str] = "robocal.joints"
    q: tuple[float, ...]
    qs: tuple[float, ...] | None = None

    def check(self) -> None:
        super().check()
        check_finite("q", self.q, JOINT_LIMIT_RAD)
        if self.qs is not None:
            check_finite("qs", self.qs, JOINT_LIMIT_RAD)
            _same_length(self.qs, self.q, "{} secondary encoders for {} joints")


@dataclass(frozen=True, kw_only=True)
class TrackerSample(Stamped):
    """A measured probe pose (m, unit quaternion) in ``frame`` (``"base"`` or ``"tracker"``)."""

    SCHEMA: ClassVar[str] = "robocal.tracker"
    xyz: tuple[float, float, float]
    quat: tuple[float, float, float, float]
    frame: str = "base"

    def check(self) -> None:
        super().check()
        check_finite("xyz", self.xyz, POSITION_LIMIT_M, length=3)
        check_finite("quat", self.quat, 10.0, length=4)
        norm = math.sqrt(sum(v * v for v in self.quat))
        if abs(norm - 1.0) > QUATERNION_TOLERANCE:
            raise RejectedMessageError("quaternion", f"quaternion norm {norm:.5f}, expected 1")
        if self.frame not in ("base", "tracker"):
            raise RejectedMessageError(
                "out_of_range", f"frame must be base|tracker, got {self.frame!r}"
            )


@dataclass(frozen=True, kw_only=True)
class TemperatureSample(Stamped):
    """Temperatures (°C) of the named sensors at time ``t``."""

    SCHEMA: ClassVar[str] = "robocal.temperature"
    names: tuple[str, ...]
    values: tuple[float, ...]

    def check(self) -> None:
        if not self.names:
            raise RejectedMessageError("invalid", "a temperature sample needs at least one name")
        self.check_values()

    def check_values(self) -> None:
        """The checks without the non-empty rule (a data point may carry no temperatures)."""
        Stamped.check(self)
        lo, hi = TEMPERATURE_RANGE_C
        for name, v in zip(self.names, self.values, strict=False):
            if not (isinstance(v, int | float) and math.isfinite(v)):
                raise RejectedMessageError("non_finite", f"temperature {name!r} is {v!r}")
            if not lo <= v <= hi:
                raise RejectedMessageError(
                    "out_of_range", f"temperature {name!r} {v} °C not in {lo}…{hi}"
                )
        if not all(isinstance(n, str) and n for n in self.names):
            raise RejectedMessageError(
                "malformed", f"temperature names must be strings: {self.names}"
            )
        if len(set(self.names)) != len(self.names):
            raise RejectedMessageError("invalid", f"temperature names repeat: {self.names}")
        _same_length(self.names, self.values, "{} names, {} values")


@dataclass(frozen=True, kw_only=True)
class DataPoint(Stamped):
    """One joined measurement: settled joints, temperatures and the tracker pose at ``t``."""

    SCHEMA: ClassVar[str] = "robocal.points"
    q: tuple[float, ...]
    xyz: tuple[float, float, float]
    quat: tuple[float, float, float, float]
    frame: str = "base"
    qs: tuple[float, ...] | None = None
    temperature_names: tuple[str, ...] = ()
    temperatures: tuple[float, ...] = ()

    @classmethod
    def join(
        cls,
        joint: JointSample,
        tracker: TrackerSample,
        temperature: TemperatureSample | None = None,
    ) -> DataPoint:
        """The point ``tracker`` measured at ``joint``'s angles and ``temperature``'s readings
        (none: no temperatures), numbered and timed as the tracker sample."""
        return cls(
            seq=tracker.seq,
            t=tracker.t,
            q=tuple(joint.q),
            qs=None if joint.qs is None else tuple(joint.qs),
            xyz=tuple(tracker.xyz),
            quat=tuple(tracker.quat),
            frame=tracker.frame,
            temperature_names=() if temperature is None else tuple(temperature.names),
            temperatures=() if temperature is None else tuple(temperature.values),
        )

    def check(self) -> None:
        JointSample(seq=self.seq, t=self.t, q=self.q, qs=self.qs).check()
        TrackerSample(
            seq=self.seq, t=self.t, xyz=self.xyz, quat=self.quat, frame=self.frame
        ).check()
        TemperatureSample(
            seq=self.seq, t=self.t, names=self.temperature_names, values=self.temperatures
        ).check_values()


@dataclass(frozen=True, kw_only=True)
class Batch:
    """``n_B`` consecutive data points: ``seq`` numbers the batches of one window ``epoch`` (the
    window's run, ms since 1970, kept across restarts with its state); ``first`` is the index of
    the batch's first point among every point that window epoch emitted."""

    SCHEMA: ClassVar[str] = "robocal.batches"
    seq: int
    points: tuple[DataPoint, ...]
    epoch: int = 0
    first: int = 0

    def check(self) -> None:
        for name in ("seq", "epoch", "first"):
            check_count(name, getattr(self, name))
        for p in self.points:
            p.check()


@dataclass(frozen=True, kw_only=True)
class ModelHeader:
    """What travels in front of a snapshot's safetensors bytes."""

    SCHEMA: ClassVar[str] = "robocal.model"
    model_version: int
    robot: str
    n_seen: int
    t: float

    def check(self) -> None:
        check_count("model_version", self.model_version)
        check_count("n_seen", self.n_seen)
        if not isinstance(self.robot, str) or not self.robot:
            raise RejectedMessageError("malformed", f"robot must be a name, got {self.robot!r}")
        _check_time(self.t)


@dataclass(frozen=True, kw_only=True)
class Metrics:
    """One learner update: version, counts, timing and errors (mm), uncertainty (mm), and the
    poisoning defence's cumulative counts (``quarantined`` points, ``withheld`` updates)."""

    SCHEMA: ClassVar[str] = "robocal.metrics"
    model_version: int
    n_seen: int
    memory_size: int
    train_time_s: float
    test_mean_mm: float
    test_max_mm: float
    batch_mean_mm: float
    aleatoric_mm: float
    epistemic_mm: float
    epistemic_p90_mm: float
    memory_age: tuple[int, ...] = ()
    quarantined: int = 0  # points kept out by the quarantine, cumulative
    withheld: int = 0  # updates the publish gate withheld, cumulative
    t: float = 0.0

    def check(self) -> None:
        for f in fields(self):
            value = getattr(self, f.name)
            items = value if f.name == "memory_age" else (value,)
            if not all(type(v) in _NUMBER for v in items):  # NaN is allowed (no test set yet)
                raise RejectedMessageError("malformed", f"metrics.{f.name} is not numeric")


@dataclass(frozen=True, kw_only=True)
class Diagnostics:
    """Per-stage counts of dropped messages by reason and of accepted ones, and the last
    refusal of each kind (e.g. why a model was not adopted)."""

    SCHEMA: ClassVar[str] = "robocal.diagnostics"
    stage: str
    accepted: int
    dropped: dict[str, int] = field(default_factory=dict)
    t: float = 0.0
    refused: dict[str, str] = field(default_factory=dict)

    def check(self) -> None:
        check_count("accepted", self.accepted)
        if not isinstance(self.dropped, dict) or not all(
            isinstance(v, int) for v in self.dropped.values()
        ):
            raise RejectedMessageError("malformed", "diagnostics.dropped must map reasons to ints")


STREAM_TYPES: dict[str, type] = {
    "joints": JointSample,
    "tracker": TrackerSample,
    "temperature": TemperatureSample,
    "points": DataPoint,
    "batches": Batch,
    "metrics": Metrics,
    "diagnostics": Diagnostics,
}


def check_count(name: str, value: Any) -> None:
    """An int in ``0..MAX_SEQ`` (a sequence number, version or count), else out_of_range."""
    if type(value) is not int or not 0 <= value <= MAX_SEQ:
        raise RejectedMessageError(
            "out_of_range", f"{name} must be an int in 0..{MAX_SEQ}, got {value!r:.40}"
        )


def _check_time(t: Any) -> None:
    if type(t) not in _NUMBER or not math.isfinite(t):
        raise RejectedMessageError("non_finite", f"t is {t!r:.40}")
    if abs(t) > MAX_TIME_S:
        raise RejectedMessageError("out_of_range", f"t = {t} s beyond ±{MAX_TIME_S:g} s")


def _same_length(a: tuple, b: tuple, detail: str) -> None:
    """joint_count unless ``a`` and ``b`` are as long; ``detail`` formats both lengths."""
    if len(a) != len(b):
        raise RejectedMessageError("joint_count", detail.format(len(a), len(b)))


def check_finite(name: str, values: tuple, limit: float, length: int | None = None) -> None:
    """Raise RejectedMessageError (non_finite / out_of_range / malformed) unless ``values`` are
    ``length`` finite numbers within ``±limit``."""
    if length is not None and len(values) != length:
        raise RejectedMessageError("malformed", f"{name} needs {length} values, got {len(values)}")
    if all(type(v) in _NUMBER and -limit <= v <= limit for v in values):
        return  # the fast path; NaN and inf fail the comparison
    for i, v in enumerate(values):
        if type(v) not in _NUMBER or not math.isfinite(v):
            raise RejectedMessageError("non_finite", f"{name}[{i}] is {v!r}")
        if abs(v) > limit:
            raise RejectedMessageError("out_of_range", f"{name}[{i}] = {v} beyond ±{limit}")


_NUMBER = (int, float)
