"""Robots nobody has seen: random DH arms, random sensor layouts, one hidden effect each.

A check of the gap workflow on robots that are not in ``kinematics/robots`` and on data made
by code that shares nothing with the workflow's effect models. The forward kinematics, the
gravity torques and every hidden effect here are written from the physics directly (a DH
product, ``tau_i = sum_j m_j g0 [z_i x (c_j - o_i)]_z``, a link's strain times its length, ...);
only the description and dataset *formats* are shared.

Each :class:`UnseenSpec` draws (seeded) an arm of 5-7 revolute axes, with or without link
masses and secondary encoders, 1-16 thermometers with random names, a campaign of random poses
over hours of warm-up, and at most one hidden effect of DESIGN.md's vocabulary (or one of
:data:`UNNAMED`, which no product model names) scaled so that its mean position contribution is
``magnitude`` times the noise floor. ``also`` adds further effects, each scaled alone to its
own magnitude (a realistic robot: an uncalibrated geometry plus a smaller non-geometric effect).

>>> ds, desc, truth = unseen_campaign(UnseenSpec(seed=3, n_points=20))
>>> 5 <= desc.n_joints <= 7, len(ds), truth["hidden"]
(True, 20, None)
"""

from __future__ import annotations

import string
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pandas as pd

from kinematics.dataset import Dataset, DatasetMeta, temperature_column, write_dataset
from kinematics.description import JointDH, RobotDescription, description_to_toml
from kinematics.effects import EFFECTS
from kinematics.transforms import transform_from_xyz_rpy, xyz_quat_from_transform

#: The effect names a hidden effect is drawn from: the registry of kinematics.effects.
VOCABULARY = tuple(EFFECTS)
#: Effects outside the vocabulary, which no model of the product names: a joint's error driven
#: by another joint's angle (cross-coupled transmissions, cable and hose forces).
UNNAMED = ("joint_coupling",)
#: Effects that need a signal a robot may lack: link masses for gravity torques.
NEEDS_MASSES = ("joint_compliance",)
G0_M_S2 = 9.81


@dataclass(frozen=True, kw_only=True)
class UnseenSpec:
    """One random robot and campaign. ``n_axes``/``n_thermometers``/``with_*`` of None are drawn
    from the seed; ``hidden`` is a vocabulary effect or None; ``magnitude`` in noise floors;
    ``also`` further ``(effect, magnitude)`` pairs on top of ``hidden``."""

    seed: int
    n_points: int = 400
    hidden: str | None = None
    magnitude: float = 3.0
    n_axes: int | None = None
    n_thermometers: int | None = None
    with_masses: bool | None = None
    with_secondary: bool | None = None
    noise_m: float = 25e-6
    joint_span_deg: float | None = None
    also: tuple[tuple[str, float], ...] = ()

    def __post_init__(self) -> None:
        for name in (self.hidden, *(name for name, _ in self.also)):
            if name is not None and name not in VOCABULARY + UNNAMED:
                raise ValueError(
                    f"hidden must be one of {VOCABULARY + UNNAMED} or None, got {name!r}"
                )
        if self.n_axes is not None and not 5 <= self.n_axes <= 7:
            raise ValueError(f"n_axes must be in 5..7, got {self.n_axes}")


def random_name(rng: np.random.Generator, length: int = 6) -> str:
    """A random lowercase identifier (letters, digits, underscores), never a reference name."""
    letters = rng.choice(list(string.ascii_lowercase), size=length)
    return "".join(letters)


def random_robot(rng: np.random.Generator, n_axes: int, with_masses: bool) -> RobotDescription:
    """A random serial arm: link lengths 0.05-0.9 m, twists of 0 / ±90° (plus a few degrees),
    limits ±100-170°, masses 3-80 kg (or none), a tool 0.1-0.3 m out."""
    joints = []
    for i in range(n_axes):
        twist = rng.choice([0.0, 90.0, -90.0]) if i else rng.choice([90.0, -90.0])
        mass = float(rng.uniform(3, 80) * (1 - i / (n_axes + 1))) if with_masses else 0.0
        joints.append(
            JointDH(
                a_m=float(rng.uniform(0.05, 0.9) if rng.random() < 0.7 else 0.0),
                d_m=float(rng.uniform(0.05, 0.9) if rng.random() < 0.6 else 0.0),
                alpha_deg=float(twist + rng.uniform(-3, 3)),
                offset_deg=float(rng.uniform(-30, 30)),
                lower_deg=-float(rng.uniform(100, 170)),
                upper_deg=float(rng.uniform(100, 170)),
                mass_kg=mass,
                com_m=tuple(float(c) for c in rng.uniform(-0.2, 0.2, 3)) if mass else (0, 0, 0),
            )
        )
    tool = transform_from_xyz_rpy(
        [0.0, 0.0, float(rng.uniform(0.1, 0.3))], np.deg2rad(rng.uniform(-10, 10, 3))
    )
    return RobotDescription(name=f"arm_{random_name(rng)}", joints=tuple(joints), tool=tool)


def _rot(axis: int, angle: np.ndarray) -> np.ndarray:
    c, s = np.cos(angle), np.sin(angle)
    R = np.zeros(np.shape(angle) + (4, 4))
    i, j = [k for k in range(3) if k != axis]
    R[..., axis, axis] = R[..., 3, 3] = 1.0
    R[..., i, i] = R[..., j, j] = c
    R[..., i, j], R[..., j, i] = (-s, s) if axis != 1 else (s, -s)
    return R


def _trans(v: np.ndarray) -> np.ndarray:
    T = np.zeros(np.shape(v)[:-1] + (4, 4))
    T[..., :3, 3] = v
    T[..., [0, 1, 2, 3], [0, 1, 2, 3]] = 1.0
    return T


def frames(q: np.ndarray, dh: np.ndarray) -> np.ndarray:
    """Frames ``(N, n + 1, 4, 4)`` of ``prod Rz(q + offset) Tx(a) Tz(d) Rx(alpha) Ry(beta)``
    for angles ``(N, n)`` and a DH table ``(N, n, 5)`` (a, d, alpha, beta, offset; m, rad)."""
    N, n = q.shape
    out = np.zeros((N, n + 1, 4, 4))
    out[:, 0] = np.eye(4)
    zero = np.zeros(N)
    for i in range(n):
        a, d, al, be, off = (dh[:, i, k] for k in range(5))
        step = _rot(2, q[:, i] + off) @ _trans(np.stack([a, zero, d], -1))
        out[:, i + 1] = out[:, i] @ step @ _rot(0, al) @ _rot(1, be)
    return out


def gravity_torques(desc: RobotDescription, q: np.ndarray) -> np.ndarray:
    """Holding torques ``(N, n)`` N·m of the links' weights (mass at ``com_m`` in DH frame i)."""
    dh = np.broadcast_to(_table(desc), (len(q), desc.n_joints, 5))
    F = frames(q, dh)
    tau = np.zeros(q.shape)
    for j, joint in enumerate(desc.joints):
        if joint.mass_kg == 0:
            continue
        c = (F[:, j + 1] @ np.r_[joint.com_m, 1.0])[:, :3]
        for i in range(j + 1):
            z, o = F[:, i, :3, 2], F[:, i, :3, 3]
            tau[:, i] += joint.mass_kg * G0_M_S2 * np.cross(z, c - o)[:, 2]
    return tau


def _table(desc: RobotDescription) -> np.ndarray:
    return np.array(
        [[j.a_m, j.d_m, *np.deg2rad([j.alpha_deg, j.beta_deg, j.offset_deg])] for j in desc.joints]
    )


def temperatures(rng: np.random.Generator, t: np.ndarray, k: int) -> np.ndarray:
    """``k`` thermometers (N, k) °C: each warms by 3-40 K with its own time constant and swings
    with its own period and phase, plus 0.05 K noise."""
    hours = t / 3600.0
    rise, tau = rng.uniform(3, 40, k), rng.uniform(0.3, 4.0, k)
    swing, period, phase = rng.uniform(0.5, 4, k), rng.uniform(1, 6, k), rng.uniform(0, 6.3, k)
    base = 18 + 6 * rng.random()
    T = (
        base
        + rise * (1 - np.exp(-hours[:, None] / tau))
        + swing * np.sin(2 * np.pi * hours[:, None] / period + phase)
    )
    return T + rng.normal(0, 0.05, T.shape)


def _hidden(name, rng, desc, q, t, temps, approach):
    """The hidden effect's changes at unit scale: joint offsets (N, n), DH deltas (N, n, 5),
    base and tool corrections (N, 4, 4), and what it was (for the truth record)."""
    N, n = q.shape
    dq, ddh = np.zeros((N, n)), np.zeros((N, n, 5))
    base, tool = np.broadcast_to(np.eye(4), (N, 4, 4)), np.broadcast_to(np.eye(4), (N, 4, 4))
    small = np.r_[rng.normal(0, 1e-3, 3), rng.normal(0, 1e-3, 3)]
    frame = _trans(small[:3]) @ _rot(0, small[3]) @ _rot(1, small[4]) @ _rot(2, small[5])
    info: dict = {}
    if name == "geometric":
        ddh[:] = rng.normal(0, [1e-3, 1e-3, 1e-3, 0.0, 1e-3], (n, 5))
    elif name == "joint_compliance":
        dq = -rng.uniform(0.5, 2.0, n) * 1e-6 * gravity_torques(desc, q)
    elif name == "thermal_expansion":
        k = temps.shape[1]
        W = np.zeros((n, k))
        for i in range(n):
            W[i, rng.choice(k, size=min(k, 1 + int(rng.integers(2))), replace=False)] = 1
        W /= W.sum(axis=1, keepdims=True)
        strain = 11.5e-6 * (temps - 20.0) @ W.T  # (N, n)
        ddh[:, :, 0] = strain * _table(desc)[None, :, 0]
        ddh[:, :, 1] = strain * _table(desc)[None, :, 1]
        info["link_weights"] = W.tolist()
    elif name == "backlash":
        dq = -rng.uniform(0.5, 1.0, n) * 1e-4 * approach
    elif name == "gear_periodic":
        order = int(rng.integers(1, 4))
        amp, phase = rng.uniform(0.2, 1.0, n) * 1e-4, rng.uniform(0, 6.3, n)
        dq = amp * np.sin(order * q + phase)
        info["order"] = order
    elif name == "joint_coupling":
        other = (np.arange(n) + rng.integers(1, n, n)) % n  # never the joint itself
        amp, phase = rng.uniform(0.2, 1.0, n) * 1e-4, rng.uniform(0, 6.3, n)
        dq = amp * np.sin(q[:, other] + phase)
        info["coupled_to"] = (other + 1).tolist()
    elif name == "tracker_drift":
        hours = (t / 3600.0)[:, None]
        drift = hours * np.r_[rng.normal(0, 1e-4, 3), rng.normal(0, 2e-5, 3)]
        base = _trans(drift[:, :3]) @ _rot(0, drift[:, 3]) @ _rot(1, drift[:, 4])
    elif name == "base_frame":
        base = np.broadcast_to(frame, (N, 4, 4))
    elif name == "tool_frame":
        tool = np.broadcast_to(frame, (N, 4, 4))
    return dq, ddh, base, tool, info


def _poses(desc, q, dq, ddh, base, tool) -> np.ndarray:
    dh = _table(desc)[None] + ddh
    return base @ frames(q + dq, dh)[:, -1] @ desc.tool[None] @ tool


def unseen_campaign(spec: UnseenSpec) -> tuple[Dataset, RobotDescription, dict]:
    """The dataset, the robot's nominal description and a truth record for ``spec``.

    The dataset's ``meta.robot`` is the robot's name; :func:`write_unseen` writes the
    description to a file and points the metadata at that path.
    """
    rng = np.random.default_rng(spec.seed)
    n = spec.n_axes or int(rng.integers(5, 8))
    masses = bool(rng.random() < 0.5) if spec.with_masses is None else spec.with_masses
    masses = masses or any(e in NEEDS_MASSES for e in (spec.hidden, *(e for e, _ in spec.also)))
    secondary = bool(rng.random() < 0.5) if spec.with_secondary is None else spec.with_secondary
    k = spec.n_thermometers or int(rng.integers(1, 17))
    desc = random_robot(rng, n, masses)
    N = spec.n_points
    lim = desc.limits_rad
    if spec.joint_span_deg is not None:  # a narrow campaign around the middle of the range
        lim = lim.mean(axis=1)[:, None] + np.deg2rad(spec.joint_span_deg) / 2 * np.array([-1, 1])
    q = rng.uniform(lim[:, 0] * 0.9, lim[:, 1] * 0.9, (N, n))
    t = np.sort(rng.uniform(0, 8 * 3600.0, N))
    names = [random_name(rng, int(rng.integers(2, 9))) for _ in range(k)]
    names = [f"{s}{i}" for i, s in enumerate(names)]  # distinct
    temps = temperatures(rng, t, k)
    d = np.diff(q, axis=0)
    approach = np.concatenate([np.sign(d[:1]), np.sign(d)]) if N > 1 else np.ones((N, n))
    approach[approach == 0] = 1.0
    zero = np.zeros((N, n)), np.zeros((N, n, 5)), np.broadcast_to(np.eye(4), (N, 4, 4))
    nominal = _poses(desc, q, zero[0], zero[1], zero[2], zero[2])
    info: dict = {}
    dq, ddh, base, tool = zero[0], zero[1], zero[2], zero[2]
    deflection = zero[0]  # what secondary encoders see: the compliance part of dq
    effects = ([(spec.hidden, spec.magnitude)] if spec.hidden else []) + list(spec.also)
    for name, magnitude in effects:
        e_dq, e_ddh, e_base, e_tool, e_info = _hidden(name, rng, desc, q, t, temps, approach)
        moved = _poses(desc, q, e_dq, e_ddh, e_base, e_tool)
        mean = float(np.linalg.norm(moved[:, :3, 3] - nominal[:, :3, 3], axis=1).mean())
        noise_floor = spec.noise_m * np.sqrt(8 / np.pi)  # E|N(0, s^2 I3)|
        s = magnitude * noise_floor / mean
        dq, ddh = dq + s * e_dq, ddh + s * e_ddh
        deflection = deflection + (s * e_dq if name == "joint_compliance" else 0)
        base, tool = base @ _scaled(e_base, s), tool @ _scaled(e_tool, s)
        info = e_info | info
    true = _poses(desc, q, dq, ddh, base, tool)
    noise = rng.normal(0, spec.noise_m, (N, 3))
    measured = true.copy()
    measured[:, :3, 3] += noise
    measured[:, :3, :3] = _small_rotations(rng, N, 5e-6) @ measured[:, :3, :3]
    table = {"t": t, **{f"q{i + 1}": q[:, i] for i in range(n)}}
    if secondary:
        qs = q + deflection + rng.normal(0, 2e-6, q.shape)
        table |= {f"qs{i + 1}": qs[:, i] for i in range(n)}
    table |= {temperature_column(name): temps[:, c] for c, name in enumerate(names)}
    xyz, quat = xyz_quat_from_transform(measured)
    table |= dict(zip("xyz", xyz.T, strict=True))
    table |= dict(zip(("qx", "qy", "qz", "qw"), quat.T, strict=True))
    floor = float(np.linalg.norm(noise, axis=1).mean())
    meta = DatasetMeta(robot=desc.name, frame="base", noise_floor_m=floor)
    truth = {"hidden": spec.hidden, "magnitude": spec.magnitude, "also": list(spec.also)}
    truth |= {"n_axes": n, "masses": masses}
    truth |= {"secondary": secondary, "thermometers": names, **info}
    return Dataset(pd.DataFrame(table), meta), desc, truth


def _scaled(T: np.ndarray, s: float) -> np.ndarray:
    """A rigid correction scaled by ``s`` in translation and rotation angle (small angles)."""
    out = np.array(T, dtype=float)
    out[..., :3, 3] *= s
    W = 0.5 * (out[..., :3, :3] - np.swapaxes(out[..., :3, :3], -1, -2)) * s
    out[..., :3, :3] = _expm_skew(W)
    return out


def _expm_skew(W: np.ndarray) -> np.ndarray:
    w = np.stack([W[..., 2, 1], W[..., 0, 2], W[..., 1, 0]], -1)
    th = np.linalg.norm(w, axis=-1)[..., None, None]
    th = np.where(th == 0, 1e-30, th)
    eye = np.broadcast_to(np.eye(3), W.shape)
    return eye + np.sin(th) / th * W + (1 - np.cos(th)) / th**2 * (W @ W)


def _small_rotations(rng: np.random.Generator, N: int, sigma: float) -> np.ndarray:
    w = rng.normal(0, sigma, (N, 3))
    W = np.zeros((N, 3, 3))
    W[:, 0, 1], W[:, 0, 2], W[:, 1, 2] = -w[:, 2], w[:, 1], -w[:, 0]
    return _expm_skew(W - np.swapaxes(W, 1, 2))


def write_unseen(spec: UnseenSpec, out_dir: str | Path) -> tuple[Path, RobotDescription, dict]:
    """Write ``robot.toml`` and ``data.parquet`` into ``out_dir``; the dataset's ``meta.robot``
    is the TOML file's absolute path. Returns the dataset path, description and truth."""
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    ds, desc, truth = unseen_campaign(spec)
    robot = out / "robot.toml"
    robot.write_text(description_to_toml(desc))
    meta = DatasetMeta(**{**ds.meta.__dict__, "robot": str(robot.resolve())})
    return write_dataset(Dataset(ds.table, meta), out / "data.parquet"), desc, truth


__all__ = [
    "UNNAMED",
    "VOCABULARY",
    "UnseenSpec",
    "frames",
    "gravity_torques",
    "random_robot",
    "unseen_campaign",
    "write_unseen",
]
