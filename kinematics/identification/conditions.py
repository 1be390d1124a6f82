"""From a dataset to observations: the per-point conditions effects depend on and the
measured poses, in the frame the dataset states.

The approach direction per joint comes from ``approach1..n`` columns when the dataset has
them (``true_approach1..n`` in a simulated one); otherwise it is inferred from the sign of
``q_k - q_{k-1}`` in row order (the first
row takes the second's sign) and :attr:`Observations.notes` says so.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from kinematics import identity
from kinematics.dataset import Dataset, temperature_columns, temperature_name
from kinematics.description import RobotDescription
from kinematics.effects._base import Conditions
from kinematics.frames import fit_frames
from kinematics.model import RobotModel


@dataclass(frozen=True, kw_only=True)
class Observations:
    """Conditions and measured poses ``T_measured`` (N, 4, 4) in a frame ``T_W_0`` away from
    the robot base (identity when the dataset is in the base frame)."""

    cond: Conditions
    T_measured: np.ndarray
    T_W_0: np.ndarray
    notes: tuple[str, ...] = ()

    @property
    def n_points(self) -> int:
        return self.cond.n_points

    def subset(self, index: np.ndarray) -> Observations:
        """The points at ``index``; conditions and poses sliced alike."""
        index = np.asarray(index)
        c = self.cond
        cond = replace(
            c,
            q=c.q[index],
            t=c.t[index],
            temperatures=None if c.temperatures is None else c.temperatures[index],
            approach=None if c.approach is None else c.approach[index],
            tool_force_n=None if c.tool_force_n is None else c.tool_force_n[index],
            payload_kg=c.payload_kg if np.ndim(c.payload_kg) == 0 else c.payload_kg[index],
        )
        return replace(self, cond=cond, T_measured=self.T_measured[index])


def check_match(desc: RobotDescription, ds: Dataset) -> None:
    """Raise :class:`DatasetError` when the dataset is not of this robot (the one rule of
    :func:`kinematics.identity.check_match`: joint count and robot name)."""
    identity.check_match(desc, ds)


def cell_description(desc: RobotDescription, ds: Dataset) -> RobotDescription:
    """``desc`` with the dataset's ``T_6_S`` when its metadata knows it."""
    return desc if ds.meta.T_6_S is None else desc.with_tool(np.asarray(ds.meta.T_6_S, float))


def infer_approach(q: np.ndarray) -> np.ndarray:
    """Approach sign per joint ``(N, n)`` from consecutive rows (+1 when arriving upward).

    >>> infer_approach(np.array([[0.0], [1.0], [0.5]])).ravel().tolist()
    [1.0, 1.0, -1.0]
    """
    d = np.diff(q, axis=0)
    sign = np.where(d >= 0, 1.0, -1.0)
    return np.concatenate([sign[:1], sign], axis=0) if len(sign) else np.ones_like(q)


def _columns(ds: Dataset, names: list[str], true_names: list[str], what: str, notes: list[str]):
    """The columns ``names`` if present, else the simulator's ``true_names`` (noted)."""
    t = ds.table
    if all(c in t.columns for c in names):
        return t[names].to_numpy(float)
    if all(c in t.columns for c in true_names):
        notes.append(
            f"{what} taken from the simulator's {true_names[0].rstrip('0123456789')}* "
            "columns (a real cell knows its program)"
        )
        return t[true_names].to_numpy(float)
    return None


def observations_from_dataset(ds: Dataset, desc: RobotDescription) -> Observations:
    """The observations of ``ds`` for robot ``desc`` (checked to match).

    Loads and approach directions are conditions a cell knows from its program; a simulated
    dataset carries them as ``true_payload_kg``, ``true_f{x,y,z}_n`` and ``true_approach{i}``,
    used when the plain columns (``payload_kg``, ``force_{x,y,z}_n``, ``approach{i}``) are absent.
    """
    check_match(desc, ds)
    n = desc.n_joints
    notes: list[str] = []
    q = ds.q()
    approach = _columns(
        ds,
        [f"approach{i}" for i in range(1, n + 1)],
        [f"true_approach{i}" for i in range(1, n + 1)],
        "approach directions",
        notes,
    )
    if approach is None:
        approach = infer_approach(q)
        notes.append("approach direction inferred from the sign of q_k - q_(k-1) in row order")
    force = _columns(
        ds, [f"force_{c}_n" for c in "xyz"], [f"true_f{c}_n" for c in "xyz"], "tool forces", notes
    )
    payload = _columns(ds, ["payload_kg"], ["true_payload_kg"], "payloads", notes)
    temp_cols = temperature_columns(ds.table)
    cond = Conditions(
        q=q,
        t=ds.table["t"].to_numpy(float),
        temperatures=ds.temperatures(),
        temperature_names=tuple(temperature_name(c) for c in temp_cols),
        approach=np.sign(approach),
        payload_kg=0.0 if payload is None else payload[:, 0],
        tool_force_n=force,
    )
    if ds.meta.frame == "base":
        T_W_0 = np.eye(4)
    elif ds.meta.T_W_0 is not None:
        T_W_0 = np.asarray(ds.meta.T_W_0, dtype=float)
    else:
        flange = RobotModel(desc).fk(q, frame="flange")
        T_W_0 = fit_frames(ds.measured_poses(), flange, T_6_S_init=desc.tool).T_W_0
        notes.append("T_W_0 unknown in the metadata: identified by AX = ZB (kinematics.frames)")
    return Observations(cond=cond, T_measured=ds.measured_poses(), T_W_0=T_W_0, notes=tuple(notes))
