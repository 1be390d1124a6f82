"""Measurement programs: which joint targets the cell visits, in which order, when, under load.

A program is a sequence of visits. For visit ``k`` the robot leaves the previous target at
``t_depart_s``, reaches a pre-position ``q_pre`` (the target backed off by ``approach_rad``
against the approach sign) at ``t_pre_s``, moves onto the target ``q`` at ``t_arrive_s``, has
settled at ``t_settled_s`` and is measured by the tracker until ``t_leave_s``. Approach signs
are balanced per joint (half +1, half -1), so every joint is seen from both sides. Between
blocks of points the cell runs warm-up phases (robot exercising, heating 1) and cool-down
phases (robot idle, heating 0); while measuring the robot heats moderately
(``measure_heating``). Payload and air-spring force are switched in episodes.
Targets are random inside the joint limits, kept only if the tracker can see the probe
(:mod:`kinematics.measurability`) and the probe is above the floor.
"""

from __future__ import annotations

from collections.abc import Iterator
from dataclasses import dataclass, field

import numpy as np

from kinematics.effects import Conditions, perturbed_poses
from kinematics.errors import ConfigError
from kinematics.measurability import MeasurabilityConfig, measurability_from_poses
from kinematics.model import RobotModel
from kinematics.transforms import invert, transform_from_xyz_rpy

#: Phase kinds: measuring blocks, and the warm-up / cool-down phases between them.
PHASE_KINDS = ("measure", "warm_up", "cool_down")
#: Program kinds: random measurable targets, or the ISO 9283 cube pose test (sim_sources.iso_cube).
PROGRAM_KINDS = ("random", "iso9283")


@dataclass(frozen=True, kw_only=True)
class CellConfig:
    """Where the tracker stands (base frame, m, deg), what it sees, and the floor height (m)."""

    tracker_xyz_m: tuple[float, float, float] = (4.0, 0.5, 1.2)
    tracker_yaw_deg: float = 180.0
    visibility: MeasurabilityConfig = field(default_factory=MeasurabilityConfig)
    min_height_m: float = 0.3

    def T_W_0(self) -> np.ndarray:
        """The believed pose of the robot base in the tracker frame ``{W}``."""
        yaw = np.deg2rad(self.tracker_yaw_deg)
        return invert(transform_from_xyz_rpy(self.tracker_xyz_m, [0.0, 0.0, yaw]))


def measurable(T_0_S: np.ndarray, cell: CellConfig) -> np.ndarray:
    """Whether the tracker sees each probe pose ``T_0_S`` (N,) (kinematics.measurability) and
    the probe is above the floor."""
    T_W_S = cell.T_W_0()[None] @ T_0_S
    visible = measurability_from_poses(T_W_S, cell.visibility).visible
    return visible & (T_0_S[:, 2, 3] >= cell.min_height_m)


@dataclass(frozen=True, kw_only=True)
class ProgramConfig:
    """Program kind (:data:`PROGRAM_KINDS`), motion timing (rad/s, s), phases (s, heating
    0..1) and load episodes (kg, N)."""

    kind: str = "random"
    joint_speed_rad_s: float = 0.8
    approach_rad: float = float(np.deg2rad(2.0))
    approach_time_s: float = 1.0
    settle_s: float = 2.0
    measure_s: float = 1.0
    block_points: int = 250
    warm_up_s: float = 2700.0
    cool_down_s: float = 3600.0
    warm_up_heating: float = 1.0
    measure_heating: float = 0.35
    load_episode_points: int = 25
    payload_levels_kg: tuple[float, ...] = (0.0, 50.0, 100.0, 700.0)
    payload_weights: tuple[float, ...] = (0.5, 0.26, 0.22, 0.02)
    air_spring_levels_n: tuple[float, ...] = (0.0, 1000.0, 2000.0, 3000.0)

    def __post_init__(self) -> None:
        if self.kind not in PROGRAM_KINDS:
            raise ConfigError(f"program.kind must be one of {PROGRAM_KINDS}, got {self.kind!r}")
        for key in ("joint_speed_rad_s", "approach_rad", "approach_time_s", "measure_s"):
            if not getattr(self, key) > 0:
                raise ConfigError(f"program.{key} must be > 0, got {getattr(self, key)}")
        if self.block_points < 1 or self.load_episode_points < 1:
            raise ConfigError(
                f"program.block_points and load_episode_points must be >= 1, got "
                f"{self.block_points} and {self.load_episode_points}"
            )
        for key in ("warm_up_heating", "measure_heating"):
            if not 0 <= getattr(self, key) <= 1:
                raise ConfigError(f"program.{key} must be in [0, 1], got {getattr(self, key)}")
        if not self.payload_levels_kg or min(self.payload_levels_kg) < 0:
            raise ConfigError(
                f"program.payload_levels_kg must be >= 0, got {self.payload_levels_kg}"
            )
        if (
            not self.air_spring_levels_n
            or not 0 <= min(self.air_spring_levels_n) <= max(self.air_spring_levels_n) <= 3000.0
        ):
            raise ConfigError(
                "program.air_spring_levels_n must be in [0, 3000] N, got "
                f"{self.air_spring_levels_n}"
            )


@dataclass(frozen=True)
class Phase:
    """A stretch of the campaign: ``kind`` in :data:`PHASE_KINDS`, times (s), heating 0..1."""

    kind: str
    start_s: float
    end_s: float
    heating: float


@dataclass(frozen=True, kw_only=True)
class Visit:
    """One measured point of a program (times in s, angles rad controller, loads kg / N)."""

    index: int
    q_pre: np.ndarray
    q: np.ndarray
    approach: np.ndarray
    t_depart_s: float
    t_pre_s: float
    t_arrive_s: float
    t_settled_s: float
    t_leave_s: float
    payload_kg: float
    air_spring_n: float


@dataclass(frozen=True, kw_only=True)
class Program:
    """A measurement program as arrays over visits (N,) or (N, n); see the module docstring."""

    q_pre: np.ndarray
    q: np.ndarray
    approach: np.ndarray
    t_depart_s: np.ndarray
    t_pre_s: np.ndarray
    t_arrive_s: np.ndarray
    t_settled_s: np.ndarray
    t_leave_s: np.ndarray
    payload_kg: np.ndarray
    air_spring_n: np.ndarray
    phases: tuple[Phase, ...]
    info: dict = field(default_factory=dict)

    @classmethod
    def scheduled(
        cls,
        q_pre: np.ndarray,
        q: np.ndarray,
        approach: np.ndarray,
        times: np.ndarray,
        *,
        payload_kg: np.ndarray,
        air_spring_n: np.ndarray,
        phases: tuple[Phase, ...],
        info: dict | None = None,
    ) -> Program:
        """A program whose visits' depart, pre-pose, arrive, settled and leave times (s) are
        the columns of ``times`` (N, 5), as :func:`visit_schedule` gives them."""
        t_depart, t_pre, t_arrive, t_settled, t_leave = times.T
        return cls(
            q_pre=q_pre,
            q=q,
            approach=approach,
            t_depart_s=t_depart,
            t_pre_s=t_pre,
            t_arrive_s=t_arrive,
            t_settled_s=t_settled,
            t_leave_s=t_leave,
            payload_kg=payload_kg,
            air_spring_n=air_spring_n,
            phases=phases,
            info=info or {},
        )

    def __len__(self) -> int:
        return int(self.q.shape[0])

    @property
    def t_measure_s(self) -> np.ndarray:
        """The time each point is measured (the middle of its tracker window), s."""
        return 0.5 * (self.t_settled_s + self.t_leave_s)

    @property
    def duration_s(self) -> float:
        return float(self.phases[-1].end_s)

    def visit(self, k: int) -> Visit:
        return Visit(
            index=k,
            q_pre=self.q_pre[k],
            q=self.q[k],
            approach=self.approach[k],
            t_depart_s=float(self.t_depart_s[k]),
            t_pre_s=float(self.t_pre_s[k]),
            t_arrive_s=float(self.t_arrive_s[k]),
            t_settled_s=float(self.t_settled_s[k]),
            t_leave_s=float(self.t_leave_s[k]),
            payload_kg=float(self.payload_kg[k]),
            air_spring_n=float(self.air_spring_n[k]),
        )

    def visits(self) -> Iterator[Visit]:
        return (self.visit(k) for k in range(len(self)))

    def heating_schedule(self) -> tuple[np.ndarray, np.ndarray]:
        """Phase start times (s) and heating levels (0..1), for the thermal model."""
        return (
            np.array([p.start_s for p in self.phases]),
            np.array([p.heating for p in self.phases]),
        )


def sample_targets(
    model: RobotModel, cell: CellConfig, n: int, margin_rad: float, rng: np.random.Generator
) -> np.ndarray:
    """``n`` random controller targets (n, joints) inside the limits (less ``margin_rad``)
    whose nominal probe pose the tracker sees."""
    limits = model.description.limits_rad
    lo, hi = limits[:, 0] + margin_rad, limits[:, 1] - margin_rad
    found: list[np.ndarray] = []
    count, tries = 0, 0
    while count < n:
        q = rng.uniform(lo, hi, (max(4 * n, 1000), lo.size))
        ok = q[measurable(perturbed_poses(model, Conditions(q=q, t=np.zeros(len(q))), []), cell)]
        found.append(ok)
        count += len(ok)
        tries += 1
        if tries > 50 and count == 0:
            raise ConfigError("no measurable configuration found; check the cell geometry")
    return np.concatenate(found)[:n]


def balanced_signs(n: int, n_joints: int, rng: np.random.Generator) -> np.ndarray:
    """Approach signs (n, n_joints) of ±1, half of each per joint, in random order."""
    base = np.where(np.arange(n) % 2 == 0, 1.0, -1.0)
    return np.stack([rng.permutation(base) for _ in range(n_joints)], axis=1)


def balanced_levels(
    levels: tuple[float, ...], weights: tuple[float, ...], count: int, rng: np.random.Generator
) -> np.ndarray:
    """``count`` values of ``levels`` in proportion to ``weights`` (largest remainders), shuffled,
    so every campaign has the same load mix whatever its seed."""
    exact = np.asarray(weights, dtype=float) * count
    counts = np.floor(exact).astype(int)
    counts[np.argsort(counts - exact, kind="stable")[: count - counts.sum()]] += 1
    return rng.permutation(np.repeat(np.asarray(levels, dtype=float), counts))


def visit_schedule(
    t: float, q_from: np.ndarray, q_pre: np.ndarray, config: ProgramConfig
) -> tuple[float, float, float, float, float]:
    """Depart, pre-pose, arrive, settled and leave times (s) of one visit leaving at ``t``
    from joints ``q_from`` (rad) for the pre-pose ``q_pre``: the slowest joint sets the travel."""
    travel = np.max(np.abs(q_pre - q_from)) / config.joint_speed_rad_s + 0.5
    t_arrive = t + travel + config.approach_time_s
    t_settled = t_arrive + config.settle_s
    return (t, t + travel, t_arrive, t_settled, t_settled + config.measure_s)


def make_program(
    model: RobotModel,
    n: int,
    rng: np.random.Generator,
    config: ProgramConfig | None = None,
    cell: CellConfig | None = None,
) -> Program:
    """A seeded program of ``n`` measurable visits with phases and load episodes (the
    ``random`` kind; ``iso9283`` is :func:`sim_sources.iso_cube.make_cube_program`)."""
    config = config or ProgramConfig()
    cell = cell or CellConfig()
    if n < 1:
        raise ConfigError(f"a program needs n >= 1 points, got {n}")
    if config.kind != "random":
        raise ConfigError(f"make_program builds random programs, got kind {config.kind!r}")
    q = sample_targets(model, cell, n, config.approach_rad, rng)
    approach = balanced_signs(n, q.shape[1], rng)
    q_pre = q - approach * config.approach_rad
    n_episodes = -(-n // config.load_episode_points)
    episode = np.arange(n) // config.load_episode_points
    payload = balanced_levels(config.payload_levels_kg, config.payload_weights, n_episodes, rng)[
        episode
    ]
    n_air = len(config.air_spring_levels_n)
    air = balanced_levels(config.air_spring_levels_n, (1 / n_air,) * n_air, n_episodes, rng)
    air = air[episode]

    times = np.empty((n, 5))
    phases: list[Phase] = []
    t, block_start, previous = 0.0, 0.0, q_pre[0]
    for k in range(n):
        if k > 0 and k % config.block_points == 0:
            phases.append(Phase("measure", block_start, t, config.measure_heating))
            warm = (k // config.block_points) % 2 == 1
            length = config.warm_up_s if warm else config.cool_down_s
            heating = config.warm_up_heating if warm else 0.0
            phases.append(Phase("warm_up" if warm else "cool_down", t, t + length, heating))
            t = block_start = t + length
        times[k] = visit_schedule(t, previous, q_pre[k], config)
        t, previous = times[k, 4], q[k]
    phases.append(Phase("measure", block_start, t, config.measure_heating))
    return Program.scheduled(
        q_pre, q, approach, times, payload_kg=payload, air_spring_n=air, phases=tuple(phases)
    )
