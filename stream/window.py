"""Event-time join of joint, tracker and temperature samples into data points (pure).

A tracker sample at ``t_k`` becomes a :class:`~wire.messages.DataPoint` when the robot was
settled (every joint speed, from consecutive joint samples in ``[t_k - settle_window_s,
t_k + joint_tolerance_s]``, below ``settle_velocity_rad_s``), the nearest joint sample lies
within ``joint_tolerance_s`` and a temperature sample at or before ``t_k`` lies within
``temperature_tolerance_s`` (an as-of join: temperatures drift slowly and waiting for the next
1 Hz sample would add a second of latency).

Watermarks: per stream, the highest event time seen minus ``allowed_lateness_s``. A sample
older than its stream's watermark is late and dropped; a tracker sample is resolved once the
joint watermark has passed ``t_k + joint_tolerance_s`` and the temperature watermark has passed
``t_k``. Joint samples are kept until the tracker watermark (at most ``max_buffer_s``) has
passed them, since tracker samples arrive later. Duplicates (same ``seq`` and ``t``) and time
going backwards (a higher ``seq`` with an earlier ``t``) are dropped; a lower ``seq`` with a
later ``t`` is a source that restarted and is accepted. Every drop is counted by reason.

No single sample moves a watermark far: a sample more than ``max_ahead_s`` ahead of its stream's
watermark (of the other streams' before its stream's first) is refused as ``future`` unless
another stream's watermark is already near it or ``confirm_samples`` consecutive samples of its
stream agree on the jump (a line that resumes after a pause). Given the receive time, a sample
more than ``max_ahead_of_clock_s`` ahead of the wall clock is ``future`` too; replays of old
recordings lie behind the clock and pass. The thermometer names and the tracker frame are pinned
by the first sample (or ``temperature_names`` in the config); other values are refused
(``temperature_names``, ``frame``) until ``confirm_samples`` in a row agree on new ones.

>>> j = Joiner(WindowConfig(n_joints=1, require_temperatures=False, allowed_lateness_s=0.0))
>>> for i in range(30):
...     _ = j.push(JointSample(seq=i, t=i * 0.01, q=(0.1,)))
>>> tk = TrackerSample(seq=0, t=0.2, xyz=(1.0, 0.0, 0.0), quat=(0.0, 0.0, 0.0, 1.0))
>>> [p.t for p in j.push(tk)]
[0.2]
"""

from __future__ import annotations

import bisect
import math
from collections import deque
from dataclasses import dataclass

import numpy as np

from kinematics.errors import ConfigError, check_positive
from wire import (
    Batch,
    DataPoint,
    DropCounter,
    JointSample,
    TemperatureSample,
    TrackerSample,
)

Sample = JointSample | TrackerSample | TemperatureSample
_STREAM = {JointSample: "joints", TrackerSample: "tracker", TemperatureSample: "temperature"}


@dataclass(frozen=True, kw_only=True)
class WindowConfig:
    """Join tolerances (s), the settle test (rad/s), lateness (s) and the batch size ``n_B``."""

    batch_size: int = 50
    n_joints: int = 6
    joint_tolerance_s: float = 0.02
    temperature_tolerance_s: float = 2.5
    settle_window_s: float = 0.2
    settle_velocity_rad_s: float = 2e-3
    allowed_lateness_s: float = 0.5
    require_temperatures: bool = True
    max_buffer_s: float = 30.0
    seen_seqs: int = 4096
    max_ahead_s: float = 60.0
    max_ahead_of_clock_s: float = 300.0
    confirm_samples: int = 5
    temperature_names: tuple[str, ...] = ()

    def __post_init__(self) -> None:
        if self.batch_size < 1:
            raise ConfigError(f"window.batch_size must be >= 1, got {self.batch_size}")
        if self.n_joints < 1:
            raise ConfigError(f"window.n_joints must be >= 1, got {self.n_joints}")
        check_positive(
            "window",
            self,
            "joint_tolerance_s",
            "temperature_tolerance_s",
            "settle_window_s",
            "max_buffer_s",
        )
        if not self.settle_velocity_rad_s > 0:
            raise ConfigError(
                f"window.settle_velocity_rad_s must be > 0, got {self.settle_velocity_rad_s}"
            )
        check_positive("window", self, "max_ahead_s")
        if not self.max_ahead_of_clock_s >= 0:
            raise ConfigError(
                f"window.max_ahead_of_clock_s must be >= 0 (0: off), got "
                f"{self.max_ahead_of_clock_s}"
            )
        if not (isinstance(self.confirm_samples, int) and self.confirm_samples >= 1):
            raise ConfigError(
                f"window.confirm_samples must be an int >= 1, got {self.confirm_samples}"
            )
        if not (math.isfinite(self.allowed_lateness_s) and self.allowed_lateness_s >= 0):
            raise ConfigError(
                f"window.allowed_lateness_s must be >= 0, got {self.allowed_lateness_s}"
            )


class _Pinned:
    """A value fixed by its first sighting; another one replaces it only after ``confirm``
    sightings in a row (one message cannot change it, a changed installation can)."""

    def __init__(self, confirm: int, value: object = None) -> None:
        self.value, self.confirm = value, confirm
        self._candidate: object = None
        self._count = 0

    def admit(self, v: object) -> bool:
        if self.value is None or v == self.value:
            self.value, self._candidate, self._count = v, None, 0
            return True
        self._count = self._count + 1 if v == self._candidate else 1
        self._candidate = v
        if self._count >= self.confirm:
            self.value, self._candidate, self._count = v, None, 0
            return True
        return False


class _Series:
    """Time-sorted samples of one stream with watermark, duplicate and clock checks."""

    def __init__(self, seen: int) -> None:
        self.t: list[float] = []
        self.items: list[Sample] = []
        self.high = -math.inf
        self.top_seq = -1
        self.top_t = -math.inf
        self.seen: set[tuple[int, float]] = set()
        self.order: deque[tuple[int, float]] = deque(maxlen=seen)
        self._jump: list[float] = []

    def admit(
        self, s: Sample, cfg: WindowConfig, others_high: tuple[float, ...] = ()
    ) -> str | None:
        """The drop reason for ``s``, or None after inserting it in time order."""
        ident = (s.seq, s.t)
        if ident in self.seen:
            return "duplicate"
        if s.seq > self.top_seq and s.t < self.top_t:
            return "time_backwards"
        if s.t < self.high - cfg.allowed_lateness_s:
            return "late"
        if self._too_far_ahead(s.t, cfg, others_high):
            return "future"
        if len(self.order) == self.order.maxlen:
            self.seen.discard(self.order[0])
        self.order.append(ident)
        self.seen.add(ident)
        if s.t >= self.top_t:
            self.top_seq, self.top_t = s.seq, s.t
        self.high = max(self.high, s.t)
        i = bisect.bisect_right(self.t, s.t)
        self.t.insert(i, s.t)
        self.items.insert(i, s)
        return None

    def _too_far_ahead(self, t: float, cfg: WindowConfig, others_high: tuple[float, ...]) -> bool:
        """A jump of more than ``max_ahead_s`` that nothing corroborates (yet)."""
        known = [h for h in others_high if h > -math.inf]
        ref = self.high if self.high > -math.inf else max(known, default=-math.inf)
        if ref == -math.inf or t <= ref + cfg.max_ahead_s:
            self._jump.clear()
            return False
        if any(abs(t - h) <= cfg.max_ahead_s for h in known):
            self._jump.clear()
            return False  # another stream is already there
        if self._jump and self._jump[-1] <= t <= self._jump[-1] + cfg.max_ahead_s:
            self._jump.append(t)
        else:
            self._jump = [t]
        if len(self._jump) >= cfg.confirm_samples:
            self._jump.clear()
            return False  # consecutive samples agree: the stream resumed later
        return True

    def evict_before(self, t: float, keep_one: bool = False) -> None:
        i = bisect.bisect_left(self.t, t)
        if keep_one:
            i = max(i - 1, 0)
        if i > 0:
            del self.t[:i], self.items[:i]


class Joiner:
    """Joins the three source streams of one robot into data points (push, then flush)."""

    def __init__(self, cfg: WindowConfig, counter: DropCounter | None = None) -> None:
        self.cfg = cfg
        self.counter = counter or DropCounter("window")
        self._series = {name: _Series(cfg.seen_seqs) for name in _STREAM.values()}
        self._horizon = -math.inf
        self._temperature_names = _Pinned(cfg.confirm_samples, cfg.temperature_names or None)
        self._fixed_names = bool(cfg.temperature_names)
        self._frame = _Pinned(cfg.confirm_samples)

    @property
    def pending(self) -> int:
        """Tracker samples waiting for their watermarks."""
        return len(self._series["tracker"].items)

    def push(self, sample: Sample, now: float | None = None) -> list[DataPoint]:
        """Add one validated sample (received at wall-clock ``now``, s since 1970, for live
        sources); return the data points it completes (time order)."""
        reason = self._precheck(sample, now)
        stream = _STREAM[type(sample)]
        if reason is None:
            others = tuple(v.high for k, v in self._series.items() if k != stream)
            reason = self._series[stream].admit(sample, self.cfg, others)
        if reason is not None:
            self.counter.drop(reason)
            return []
        self.counter.accept()
        return self._resolve(final=False)

    def flush(self) -> list[DataPoint]:
        """End of stream: resolve every pending tracker sample with what has arrived."""
        return self._resolve(final=True)

    def _precheck(self, s: Sample, now: float | None) -> str | None:
        cfg = self.cfg
        if now is not None and cfg.max_ahead_of_clock_s and s.t > now + cfg.max_ahead_of_clock_s:
            return "future"
        if isinstance(s, JointSample) and len(s.q) != cfg.n_joints:
            return "joint_count"
        if isinstance(s, TemperatureSample):
            names = tuple(s.names)
            if self._fixed_names and names != self._temperature_names.value:
                return "temperature_names"
            if not self._temperature_names.admit(names):
                return "temperature_names"
        if isinstance(s, TrackerSample):
            if s.t - cfg.settle_window_s < self._horizon:
                return "late"
            if not self._frame.admit(s.frame):
                return "frame"
        return None

    def _resolve(self, final: bool) -> list[DataPoint]:
        cfg = self.cfg
        joints, temps, tracker = (self._series[k] for k in ("joints", "temperature", "tracker"))
        w_j = math.inf if final else joints.high - cfg.allowed_lateness_s
        w_T = math.inf if final else temps.high - cfg.allowed_lateness_s
        out = []
        while tracker.items:
            tk = tracker.items[0]
            j_ready = w_j >= tk.t + cfg.joint_tolerance_s
            if not (j_ready and (w_T >= tk.t or not cfg.require_temperatures)):
                break
            tracker.t.pop(0)
            tracker.items.pop(0)
            point, reason = self._join(tk)
            if point is None:
                self.counter.drop(reason)
            else:
                out.append(point)
        w_tr = tracker.high - cfg.allowed_lateness_s
        oldest = tracker.t[0] if tracker.t else w_tr
        horizon = max(min(oldest, w_tr, w_j), w_j - cfg.max_buffer_s) - cfg.settle_window_s
        self._horizon = max(self._horizon, horizon)
        joints.evict_before(self._horizon - cfg.joint_tolerance_s)
        temps.evict_before(self._horizon - cfg.temperature_tolerance_s, keep_one=True)
        return out

    def _join(self, tk: TrackerSample) -> tuple[DataPoint | None, str]:
        cfg = self.cfg
        joints, temps = self._series["joints"], self._series["temperature"]
        lo = bisect.bisect_left(joints.t, tk.t - cfg.settle_window_s)
        hi = bisect.bisect_right(joints.t, tk.t + cfg.joint_tolerance_s)
        window = joints.items[lo:hi]
        if not window:
            return None, "no_joints"
        nearest = min(window, key=lambda s: abs(s.t - tk.t))
        if abs(nearest.t - tk.t) > cfg.joint_tolerance_s:
            return None, "no_joints"
        if len(window) < 2 or window[-1].t - window[0].t < 0.5 * cfg.settle_window_s:
            return None, "not_settled"
        t = np.array([s.t for s in window])
        q = np.array([s.q for s in window])
        dt = np.diff(t)
        ok = dt > 0
        speed = np.abs(np.diff(q, axis=0)[ok]) / dt[ok, None]
        if speed.size == 0 or float(speed.max()) >= cfg.settle_velocity_rad_s:
            return None, "not_settled"
        temperature = None
        if cfg.require_temperatures:
            i = bisect.bisect_right(temps.t, tk.t) - 1
            if i < 0 or tk.t - temps.t[i] > cfg.temperature_tolerance_s:
                return None, "no_temperature"
            temperature = temps.items[i]
        return DataPoint.join(nearest, tk, temperature), ""


class Batcher:
    """Groups data points into batches of ``batch_size`` (a partial one on flush), numbered
    ``seq`` within ``epoch`` from ``seq``; ``count`` points were batched or pending before."""

    def __init__(self, batch_size: int, epoch: int = 0, seq: int = 0, count: int = 0) -> None:
        self.batch_size, self.epoch = batch_size, epoch
        self._points: list[DataPoint] = []
        self._seq = seq
        self.count = count

    @property
    def next_seq(self) -> int:
        """The ``seq`` of the next batch."""
        return self._seq

    @property
    def pending(self) -> tuple[DataPoint, ...]:
        """The points of the next batch so far (counted, not yet sent in a batch)."""
        return tuple(self._points)

    def add(self, points: list[DataPoint]) -> list[Batch]:
        out = []
        for p in points:
            self._points.append(p)
            self.count += 1
            if len(self._points) == self.batch_size:
                out.append(self._emit())
        return out

    def flush(self) -> list[Batch]:
        return [self._emit()] if self._points else []

    def _emit(self) -> Batch:
        batch = Batch(
            seq=self._seq,
            points=tuple(self._points),
            epoch=self.epoch,
            first=self.count - len(self._points),
        )
        self._seq += 1
        self._points = []
        return batch
