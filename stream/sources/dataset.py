"""A robocal dataset file (Parquet/CSV, e.g. ``robocal import ipa``) streamed as a live cell.

Each row is a visit: the robot settles at its joints, the tracker measures its pose at the
row's time ``t`` (or at one visit per ``period_s`` when the file has no usable time), the
temperatures are the row's. The stream is the simulated cell's (``sim_sources.streaming``:
minimum-jerk moves, joints at ``joint_rate_hz``, temperatures at ``temperature_rate_hz``) plus,
at every measurement time, a joint and a temperature sample with the row's exact values, so
that the window's settled check and event-time join give back exactly the dataset's points.
Poses in the tracker frame are moved to the base frame when the file knows ``T_W_0``.
"""

from __future__ import annotations

from collections.abc import Iterator
from dataclasses import replace

import numpy as np
import zenoh

from kinematics.dataset import (
    Dataset,
    read_dataset,
    secondary_columns,
    temperature_columns,
    temperature_name,
)
from kinematics.description import RobotDescription
from kinematics.errors import ConfigError
from kinematics.transforms import xyz_quat_from_transform
from sim_sources.streaming import Sample, StreamingConfig, cell_samples, visit_times
from stream.sources.config import DatasetSourceConfig
from stream.sources.sim import SimCellSource
from wire import JointSample, TemperatureSample, TrackerSample

POSE_COLUMNS = ["x", "y", "z", "qx", "qy", "qz", "qw"]
#: A joint sample this close (s) to a measurement time is the measurement's.
SAME_TIME_S = 1e-9


def in_base_frame(ds: Dataset) -> Dataset:
    """``ds`` with its poses in the robot base frame when it knows ``T_W_0`` (else as is)."""
    if ds.meta.frame == "base" or ds.meta.T_W_0 is None:
        return ds
    xyz, quat = xyz_quat_from_transform(ds.measured_poses_base())
    table = ds.table.copy()
    table[POSE_COLUMNS] = np.hstack([xyz, quat])
    return Dataset(table, replace(ds.meta, frame="base"))


def streaming_config(cfg: DatasetSourceConfig, ds: Dataset) -> StreamingConfig:
    """The stream's timing; ConfigError (one line) when the file's times cannot be used."""
    period = cfg.period_s or None
    streaming = StreamingConfig(
        joint_rate_hz=cfg.joint_rate_hz,
        temperature_rate_hz=cfg.temperature_rate_hz,
        settle_s=cfg.settle_s,
        dwell_s=cfg.dwell_s,
        lead_s=cfg.lead_s,
        period_s=period,
    )
    if period is None:
        if "t" not in ds.table.columns:
            raise ConfigError(f"{cfg.path}: no time column t; set period_s (s per visit)")
        t = ds.table["t"].to_numpy(float)
        if not np.all(np.isfinite(t)) or np.any(np.diff(t) <= cfg.settle_s + cfg.dwell_s):
            raise ConfigError(
                f"{cfg.path}: recorded times do not increase by more than settle_s + dwell_s = "
                f"{cfg.settle_s + cfg.dwell_s} s per row; set period_s (s per visit)"
            )
    return streaming


def dataset_samples(ds: Dataset, cfg: StreamingConfig) -> Iterator[Sample]:
    """The cell stream of ``ds`` with the rows' exact joints and temperatures at each
    measurement time (a joint sample within ``SAME_TIME_S`` of it carries the row's joints, a
    temperature sample at it is the row's); every stream numbered ``seq`` 0, 1, ... with its
    time strictly increasing."""
    tk = visit_times(ds, cfg)
    q = ds.q()
    qs_cols = secondary_columns(ds.table)
    qs = ds.table[qs_cols].to_numpy(float) if qs_cols else None
    t_cols = temperature_columns(ds.table)
    temps = ds.table[t_cols].to_numpy(float) if t_cols else None
    names = tuple(temperature_name(c) for c in t_cols)
    seq = {JointSample: 0, TrackerSample: 0, TemperatureSample: 0}

    def numbered(s: Sample) -> Sample:
        s = replace(s, seq=seq[type(s)])
        seq[type(s)] += 1
        return s

    def row_at(t: float) -> int | None:
        k = int(np.searchsorted(tk, t))
        near = [i for i in (k - 1, k) if 0 <= i < len(tk) and abs(tk[i] - t) <= SAME_TIME_S]
        return near[0] if near else None

    def joints(s: JointSample, k: int) -> JointSample:
        return replace(s, q=tuple(q[k].tolist()), qs=None if qs is None else tuple(qs[k].tolist()))

    row_joint = -1  # the last row whose exact joint sample went out
    row_temperature_t = None  # the time of the last row's exact temperature sample
    for s in cell_samples(ds, cfg):
        if isinstance(s, TemperatureSample) and row_temperature_t == s.t:
            continue  # the grid hits the measurement time: the row's sample went out already
        if isinstance(s, JointSample):
            k = row_at(s.t)
            if k is not None:
                s, row_joint = joints(s, k), k
        elif isinstance(s, TrackerSample):
            k = row_at(s.t)
            if k != row_joint:
                yield numbered(joints(JointSample(seq=0, t=s.t, q=()), k))
                row_joint = k
            if temps is not None:
                values = tuple(temps[k].tolist())
                yield numbered(TemperatureSample(seq=0, t=s.t, names=names, values=values))
                row_temperature_t = s.t
        yield numbered(s)


class DatasetSource(SimCellSource):
    """Streams a dataset file at ``speed`` x its time (see the module docstring)."""

    kind = "dataset"

    def samples(self) -> Iterator[Sample]:
        return dataset_samples(self.ds, self.cfg)


def dataset_source(
    session: zenoh.Session, cell: str, robot: str, cfg: DatasetSourceConfig, desc: RobotDescription
) -> DatasetSource:
    """Read and check ``cfg.path`` against the robot's description (ConfigError/DatasetError:
    one line) and make its source."""
    ds = in_base_frame(read_dataset(cfg.path))
    if ds.n_joints != desc.n_joints:
        raise ConfigError(f"{cfg.path}: {ds.n_joints} joints, robot {robot!r} has {desc.n_joints}")
    tool = ds.meta.T_6_S
    if tool is not None and not np.allclose(np.asarray(tool, dtype=float), desc.tool, atol=1e-9):
        xyz = np.round(np.asarray(tool, dtype=float)[:3, 3], 4).tolist()
        raise ConfigError(
            f"{cfg.path}: its probe T_6_S (at {xyz} m) is not the tool of robot {robot!r}'s "
            "description; describe the robot with that [tool] (the labels would be off by it)"
        )
    streaming = streaming_config(cfg, ds)
    return DatasetSource(
        session, cell, robot, ds, streaming, cfg.speed or None, cfg.wait_subscribers_s
    )
