"""The simulated cell as a stream: a measured dataset (timed visits) -> source samples.

Each row of a dataset is one visit: the robot arrives at ``q_k``, settles, and the tracker
measures at ``t_k``. Between visits the robot moves on a minimum-jerk profile that starts
``dwell_s`` after one measurement and ends ``settle_s`` before the next. Joint samples come at
``joint_rate_hz`` (125 Hz) while moving and settled, the tracker sample at each ``t_k``,
temperatures at ``temperature_rate_hz`` (interpolated from the rows' ``temp_*`` columns).
Deflections ``qs - q`` are interpolated the same way. Samples are yielded in source-time order;
:func:`paced` replays them in real time, at a speed factor, or as fast as possible.

>>> import pandas as pd
>>> from kinematics.dataset import Dataset, DatasetMeta
>>> rows = {"t": [2.0, 4.0], **{f"q{i}": [0.0, 0.1] for i in range(1, 7)},
...         "x": [1.0, 1.0], "y": [0.0, 0.0], "z": [0.5, 0.5],
...         "qx": [0.0, 0.0], "qy": [0.0, 0.0], "qz": [0.0, 0.0], "qw": [1.0, 1.0]}
>>> ds = Dataset(pd.DataFrame(rows), DatasetMeta(robot="ur10"))
>>> kinds = [type(s).__name__ for s in cell_samples(ds, StreamingConfig())]
>>> kinds.count("TrackerSample"), kinds.count("JointSample")
(2, 438)
"""

from __future__ import annotations

import time
from collections.abc import Callable, Iterable, Iterator
from dataclasses import dataclass

import numpy as np

from kinematics.dataset import Dataset, temperature_columns, temperature_name
from kinematics.errors import ConfigError, check_positive
from wire import JointSample, TemperatureSample, TrackerSample

Sample = JointSample | TrackerSample | TemperatureSample


@dataclass(frozen=True, kw_only=True)
class StreamingConfig:
    """Sample rates (Hz), settle time before and dwell after each measurement (s), the longest
    move (s), and an optional fixed visit period (s) that re-times the dataset's rows."""

    joint_rate_hz: float = 125.0
    temperature_rate_hz: float = 1.0
    settle_s: float = 0.5
    dwell_s: float = 0.1
    max_move_s: float = 2.0
    period_s: float | None = None
    lead_s: float = 0.5

    def __post_init__(self) -> None:
        check_positive(
            "streaming",
            self,
            "joint_rate_hz",
            "temperature_rate_hz",
            "settle_s",
            "dwell_s",
            "max_move_s",
            "lead_s",
        )
        if self.period_s is not None and not self.period_s > self.settle_s + self.dwell_s:
            raise ConfigError(
                f"streaming.period_s must exceed settle_s + dwell_s = "
                f"{self.settle_s + self.dwell_s}, got {self.period_s}"
            )


def min_jerk(s: np.ndarray) -> np.ndarray:
    """The minimum-jerk blend ``10 s^3 - 15 s^4 + 6 s^5`` of ``s`` in [0, 1]."""
    s = np.clip(s, 0.0, 1.0)
    return s**3 * (10.0 - 15.0 * s + 6.0 * s**2)


def visit_times(ds: Dataset, cfg: StreamingConfig) -> np.ndarray:
    """Measurement times (s): the dataset's ``t``, or ``lead_s + k * period_s`` when re-timed."""
    if cfg.period_s is not None:
        return cfg.lead_s + cfg.settle_s + cfg.period_s * np.arange(len(ds))
    t = ds.table["t"].to_numpy(float)
    if np.any(np.diff(t) <= cfg.settle_s + cfg.dwell_s):
        raise ConfigError(
            f"visits must be more than settle_s + dwell_s = {cfg.settle_s + cfg.dwell_s} s "
            "apart; set streaming.period_s"
        )
    return t


def cell_samples(ds: Dataset, cfg: StreamingConfig) -> Iterator[Sample]:
    """All source samples of the measurement campaign ``ds``, in source-time order."""
    tk = visit_times(ds, cfg)
    q = ds.q()
    defl = ds.deflection()
    temp_cols = temperature_columns(ds.table)
    temps = ds.table[temp_cols].to_numpy(float) if temp_cols else None
    names = tuple(temperature_name(c) for c in temp_cols)
    pose = ds.table[["x", "y", "z", "qx", "qy", "qz", "qw"]].to_numpy(float)
    dt = 1.0 / cfg.joint_rate_hz
    t0 = tk[0] - cfg.settle_s - cfg.lead_s
    grid_j = t0 + dt * np.arange(int(np.floor((tk[-1] + cfg.lead_s - t0) / dt)) + 1)
    grid_T = t0 + np.arange(
        int(np.floor((tk[-1] + cfg.lead_s - t0) * cfg.temperature_rate_hz)) + 1
    ) / (cfg.temperature_rate_hz)
    qj, dj = _trajectory(grid_j, tk, q, defl, cfg)
    events: list[tuple[float, int, int]] = [(t, 0, i) for i, t in enumerate(grid_j)]
    events += [(t, 1, i) for i, t in enumerate(tk)]
    if temps is not None:
        events += [(t, 2, i) for i, t in enumerate(grid_T)]
    events.sort()
    seq = [0, 0, 0]
    frame = ds.meta.frame
    for t, kind, i in events:
        if kind == 0:
            yield JointSample(
                seq=seq[0],
                t=float(t),
                q=tuple(qj[i].tolist()),
                qs=None if dj is None else tuple((qj[i] + dj[i]).tolist()),
            )
        elif kind == 1:
            yield TrackerSample(
                seq=seq[1],
                t=float(t),
                xyz=tuple(pose[i, :3].tolist()),
                quat=tuple(pose[i, 3:].tolist()),
                frame=frame,
            )
        else:
            values = [float(np.interp(t, tk, temps[:, c])) for c in range(temps.shape[1])]
            yield TemperatureSample(seq=seq[2], t=float(t), names=names, values=tuple(values))
        seq[kind] += 1


def _trajectory(
    grid: np.ndarray, tk: np.ndarray, q: np.ndarray, defl: np.ndarray | None, cfg: StreamingConfig
) -> tuple[np.ndarray, np.ndarray | None]:
    """Joint angles (and deflections) on ``grid``: settled at ``q[k]`` from ``tk[k] - settle_s``
    until the move to ``q[k+1]`` starts, minimum-jerk moves in between."""
    k = np.clip(np.searchsorted(tk, grid, side="left"), 0, len(tk) - 1)
    prev = np.clip(k - 1, 0, len(tk) - 1)
    arrive = tk[k] - cfg.settle_s
    depart = np.maximum(arrive - cfg.max_move_s, tk[prev] + cfg.dwell_s)
    s = np.where(k == 0, 1.0, (grid - depart) / np.maximum(arrive - depart, 1e-9))
    b = min_jerk(s)[:, None]
    qj = q[prev] + b * (q[k] - q[prev])
    dj = None if defl is None else defl[prev] + b * (defl[k] - defl[prev])
    return qj, dj


def paced(
    samples: Iterable[Sample],
    speed: float | None,
    clock: Callable[[], float] = time.monotonic,
    sleep: Callable[[float], None] = time.sleep,
) -> Iterator[Sample]:
    """Yield samples at ``speed`` x real time by their source time (``None``: no waiting)."""
    start_wall: float | None = None
    start_t = 0.0
    for s in samples:
        if speed is not None:
            if start_wall is None:
                start_wall, start_t = clock(), s.t
            wait = start_wall + (s.t - start_t) / speed - clock()
            if wait > 0:
                sleep(wait)
        yield s
