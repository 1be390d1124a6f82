"""What a model was trained on: per joint, the arc from its lowest to its highest training
angle on the circle (the circle less its largest stretch without a training angle), and per
thermometer the lowest and highest reading.

Where a command takes a joint to an angle no training point came near, the physics base and the
network both extrapolate, and neither the epistemic spread nor the intervals say so: trained on
one half of q1's range, a model's 90 % intervals cover 72-88 % of the other half on random arms
while its epistemic std there rises only 1.5-3 x (BENCHMARKS.md, "Off the training
distribution: the trained envelope"). A temperature past the readings trained on is the same
extrapolation: trained on the cooler 60 % of the paper campaign, its 90 % intervals cover 86 %
of the poses up to 0.5 K past the warmest reading trained on, 83 % at 0.5-1 K, 77 % at 2-3 K
and 68 % at 5-10 K.
Compensation marks such commands untrusted (code ``envelope``). Angles are taken on the circle,
as the kinematics and the kinematic input encoding see a joint (a ±360° wrist is one circle).
The angles seen are kept in 5° bins, so a model that goes on learning widens its envelope
exactly. Each joint and each thermometer is checked on its own: a pose whose every angle lies
in its joint's arc, in a combination never seen, passes.

>>> seen = widen(None, np.deg2rad([[10.0, -90.0], [40.0, 170.0]]), {"temp_a": [22.0, 23.5]})
>>> outside(seen, np.deg2rad([[20.0, -92.0], [120.0, 0.0]]), {"temp_a": [23.0, 23.0]}).tolist()
[False, True]
>>> why_outside(seen, np.deg2rad([120.0, 0.0]), {"temp_a": 23.0})
'q1 = 120.0 deg is more than 5 deg outside the angles trained on (10..45 deg)'
>>> why_outside(seen, np.deg2rad([20.0, 180.0]), {"temp_a": 20.5})
'temp_a = 20.5 degC is more than 0.5 K outside the temperatures trained on (22.0..23.5 degC)'
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field

import numpy as np

#: How far past a joint's arc a command is still trusted (deg): one bin either side.
MARGIN_DEG = 5.0
#: How far past a thermometer's trained readings a command is still trusted (K): about a
#: class B Pt100's tolerance at room temperature (0.4 K), and where the intervals still cover
#: (module doc).
MARGIN_K = 0.5
#: Width of one bin (deg); 72 bins make the circle.
BIN_DEG = 5.0
N_BINS = int(360 / BIN_DEG)

#: Readings by thermometer (feature name): one value or one per pose (°C).
Readings = Mapping[str, "np.ndarray | float"]


@dataclass(frozen=True)
class Envelope:
    """Per joint the 5° bins of the angles trained on (bool ``(n_joints, 72)``); per
    thermometer the lowest and highest reading trained on (°C). ``temperatures`` None: not
    recorded (a model trained before they were), so never checked, however it goes on
    learning: what it learned before is unknown."""

    joints: np.ndarray
    temperatures: dict[str, tuple[float, float]] | None = field(default_factory=dict)


def widen(
    envelope: Envelope | None, q: np.ndarray, temperatures: Readings | None = None
) -> Envelope:
    """``envelope`` (None: nothing seen) with the joint angles ``q`` ``(N, n_joints)`` (rad) and
    the thermometers' readings (°C) added."""
    q = np.atleast_2d(np.asarray(q, dtype=float))
    seen = np.zeros((q.shape[1], N_BINS), dtype=bool)
    for j, bins in enumerate(_bins(q).T):
        seen[j, bins] = True
    joints = seen if envelope is None else envelope.joints | seen
    if envelope is not None and envelope.temperatures is None:
        return Envelope(joints, None)
    ranges = {} if envelope is None else dict(envelope.temperatures)
    for name, values in (temperatures or {}).items():
        values = np.asarray(values, dtype=float)
        lo, hi = float(values.min()), float(values.max())
        if name in ranges:
            lo, hi = min(lo, ranges[name][0]), max(hi, ranges[name][1])
        ranges[name] = (lo, hi)
    return Envelope(joints, ranges)


def outside(
    envelope: Envelope,
    q: np.ndarray,
    temperatures: Readings | None = None,
    margin_deg: float = MARGIN_DEG,
    margin_k: float = MARGIN_K,
) -> np.ndarray:
    """Per pose of ``q`` ``(N, n_joints)`` (rad): does a joint lie more than ``margin_deg``
    (rounded up to whole bins) outside its arc, or a thermometer read more than ``margin_k``
    outside its trained readings? ``(N,)`` bool. Thermometers the envelope has no readings of
    are not checked."""
    known = envelope.temperatures or {}
    q = np.atleast_2d(np.asarray(q, dtype=float))
    near = _near(envelope.joints, margin_deg)
    out = ~near[np.arange(q.shape[1]), _bins(q)].all(axis=1)
    for name, values in (temperatures or {}).items():
        if name in known:
            out |= ~_within(known[name], np.broadcast_to(values, out.shape), margin_k)
    return out


def why_outside(
    envelope: Envelope,
    q: np.ndarray,
    temperatures: Mapping[str, float] | None = None,
    margin_deg: float = MARGIN_DEG,
    margin_k: float = MARGIN_K,
) -> str:
    """The first joint, then thermometer, of one pose ``q`` (rad) outside the envelope, for
    people; "" if none."""
    q = np.asarray(q, dtype=float).reshape(-1)
    near = _near(envelope.joints, margin_deg)
    for j, b in enumerate(_bins(q)):
        if not near[j, b]:
            return (
                f"q{j + 1} = {np.rad2deg(q[j]):.1f} deg is more than {margin_deg:g} deg outside "
                f"the angles trained on ({_arc_text(_arcs(envelope.joints)[j])} deg)"
            )
    known = envelope.temperatures or {}
    for name, value in (temperatures or {}).items():
        if name in known and not _within(known[name], value, margin_k):
            lo, hi = known[name]
            return (
                f"{name} = {float(value):.1f} degC is more than {margin_k:g} K outside the "
                f"temperatures trained on ({lo:.1f}..{hi:.1f} degC)"
            )
    return ""


def _within(
    trained: tuple[float, float], values: np.ndarray | float, margin_k: float
) -> np.ndarray:
    """Whether readings (°C) lie within ``margin_k`` of the ``(lowest, highest)`` trained on;
    a NaN reading does not."""
    values = np.asarray(values, dtype=float)
    return (values >= trained[0] - margin_k) & (values <= trained[1] + margin_k)


def _bins(q: np.ndarray) -> np.ndarray:
    """The bin of each angle (rad) on the circle."""
    return np.floor(np.mod(np.rad2deg(q), 360.0) / BIN_DEG).astype(int) % N_BINS


def _arcs(envelope: np.ndarray) -> np.ndarray:
    """Per joint, the bins of the arc its seen bins span: the circle less the longest run of
    unseen bins (nothing for a joint with no bin seen)."""
    arcs = np.zeros_like(envelope)
    for j, seen in enumerate(envelope):
        idx = np.flatnonzero(seen)
        if idx.size:
            steps = np.diff(np.append(idx, idx[0] + N_BINS))  # to the next seen bin, circularly
            i = int(np.argmax(steps))
            start, stop = idx[(i + 1) % idx.size], idx[i]
            arcs[j, (start + np.arange((stop - start) % N_BINS + 1)) % N_BINS] = True
    return arcs


def _near(envelope: np.ndarray, margin_deg: float) -> np.ndarray:
    """Bins within ``margin_deg`` of a joint's arc."""
    reach = int(np.ceil(margin_deg / BIN_DEG))
    arcs = _arcs(envelope)
    near = arcs.copy()
    for shift in range(1, reach + 1):
        near |= np.roll(arcs, shift, axis=1) | np.roll(arcs, -shift, axis=1)
    return near


def _arc_text(arc: np.ndarray) -> str:
    """One joint's arc in degrees, counter-clockwise from its first bin (-180..180): e.g.
    ``150..190`` crosses ±180°."""
    if arc.all():
        return "-180..180"
    first = int(np.argmax(arc & ~np.roll(arc, 1)))  # a seen bin after an unseen one
    lo = (first * BIN_DEG + 180) % 360 - 180
    hi = lo + int(arc.sum()) * BIN_DEG
    return f"{lo:g}..{hi:g}"
