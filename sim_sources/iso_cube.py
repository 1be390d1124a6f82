"""The ISO 9283 cube program: five test poses in the largest reachable cube, ``n`` cycles.

ISO 9283 (clause 6.8) places a cube in the working space with the largest volume the robot
reaches; the test poses P1-P5 lie on its diagonal plane C1-C2-C7-C8 (P1 at the centre, P2-P5
at 10 % of the plane diagonal from its corners; :func:`kinematics.iso9283.cube_test_positions`),
all with one orientation. The cube is found for any serial arm by sampling: joint
configurations inside the limits whose probe the tracker sees (:func:`sample_targets`) give
candidate centres and orientations (the nominal probe poses of those with the most room to
their joint limits); for each, the edge is bisected
while every corner and test pose is reached by damped least-squares inverse kinematics from the
centre's configuration (within the limits less the approach back-off) and every test pose is
measurable; the largest cube wins. Each cycle visits P1, P5, P4, P3, P2 (clause 7.2.1), every
pose approached from the same side (all joints from below), at constant load.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from kinematics.effects import coupling_matrix
from kinematics.errors import ConfigError
from kinematics.iso9283 import cube_test_positions
from kinematics.model import RobotModel
from kinematics.transforms import pose_error
from sim_sources.program import (
    CellConfig,
    Phase,
    Program,
    ProgramConfig,
    measurable,
    sample_targets,
    visit_schedule,
)

#: The order the poses are visited in within a cycle (ISO 9283 clause 7.2.1).
CYCLE_ORDER = ("P1", "P5", "P4", "P3", "P2")
CUBE_SEED = 9283  # the cube depends on the robot and the cell only, not the campaign seed
SAMPLES = 2000
CANDIDATES = 24
BISECTIONS = 10


@dataclass(frozen=True)
class IsoCube:
    """A reachable ISO 9283 cube: centre (m, base frame), edge (m), the test poses' common
    rotation (3, 3), their positions P1-P5 (m) and controller joint angles (5, n) rad."""

    centre_m: np.ndarray
    edge_m: float
    rotation: np.ndarray
    positions: dict[str, np.ndarray]
    q: dict[str, np.ndarray]

    def info(self) -> dict:
        """JSON-able description for the dataset metadata (``program``)."""
        return {
            "kind": "iso9283",
            "cube_centre_m": self.centre_m.tolist(),
            "cube_edge_m": self.edge_m,
            "poses": {k: v.tolist() for k, v in self.positions.items()},
            "q": {k: v.tolist() for k, v in self.q.items()},
        }


def solve_ik(
    model: RobotModel,
    target: np.ndarray,
    q_seed: np.ndarray,
    limits: np.ndarray,
    iterations: int = 60,
    tolerance: float = 1e-7,
) -> np.ndarray | None:
    """Controller angles (n,) rad reaching the pose ``target`` (4, 4) from ``q_seed`` by damped
    least squares inside ``limits`` (n, 2) rad, or None. Arms with fewer than six joints are
    asked for the position only."""
    M = coupling_matrix(model.description)
    rows = slice(0, 6) if M.shape[0] >= 6 else slice(0, 3)
    q = np.clip(np.asarray(q_seed, dtype=float), limits[:, 0], limits[:, 1])
    for _ in range(iterations):
        T, J = model.fk_and_jacobian(q[None])
        r = pose_error(target[None], T)[0][rows]
        if np.abs(r).max() < tolerance:
            return q
        Jc = (J[0] @ M)[rows]
        step = Jc.T @ np.linalg.solve(Jc @ Jc.T + 1e-6 * np.eye(Jc.shape[0]), r)
        step *= min(1.0, 0.2 / max(float(np.abs(step).max()), 1e-12))
        q = np.clip(q + step, limits[:, 0], limits[:, 1])
    T = model.fk(q[None])
    return q if np.abs(pose_error(target[None], T)[0][rows]).max() < tolerance else None


def _cube_poses(
    model: RobotModel,
    cell: CellConfig,
    centre: np.ndarray,
    rotation: np.ndarray,
    q_centre: np.ndarray,
    edge: float,
    limits: np.ndarray,
) -> dict[str, np.ndarray] | None:
    """Joint angles of the test poses when the cube of ``edge`` is reachable, else None."""
    h = 0.5 * edge
    corners = centre + h * np.array(np.meshgrid(*[[-1, 1]] * 3)).reshape(3, -1).T
    tests = cube_test_positions(centre, edge)
    q_out: dict[str, np.ndarray] = {}
    for name, p in [*tests.items(), *((f"C{k}", c) for k, c in enumerate(corners))]:
        T = np.eye(4)
        T[:3, :3], T[:3, 3] = rotation, p
        q = solve_ik(model, T, q_centre, limits)
        if q is None:
            return None
        q_out[name] = q
    q_tests = np.array([q_out[k] for k in tests])
    if not measurable(model.fk(q_tests), cell).all():
        return None
    return {k: q_out[k] for k in tests}


def find_cube(model: RobotModel, cell: CellConfig, margin_rad: float) -> IsoCube:
    """The largest reachable ISO 9283 cube of the robot in ``cell`` (see the module doc); the
    joint limits are narrowed by ``margin_rad`` for the approach back-off."""
    rng = np.random.default_rng(CUBE_SEED)
    limits = model.description.limits_rad + np.array([margin_rad, -margin_rad])
    q_samples = sample_targets(model, cell, SAMPLES, margin_rad, rng)
    poses = model.fk(q_samples)
    # candidates: the tenth of the samples farthest from their joint limits (room to move),
    # half of them nearest the middle of the seen workspace, half at random
    span = limits[:, 1] - limits[:, 0]
    room = np.minimum(q_samples - limits[:, 0], limits[:, 1] - q_samples) / span
    roomy = np.argsort(room.min(axis=1))[::-1][: max(CANDIDATES, len(q_samples) // 10)]
    mid = np.linalg.norm(poses[roomy, :3, 3] - poses[:, :3, 3].mean(axis=0), axis=1)
    picks = [*roomy[np.argsort(mid)[: CANDIDATES // 2]], *rng.choice(roomy, CANDIDATES // 2)]
    reach = float(np.ptp(poses[:, :3, 3], axis=0).max())
    best: IsoCube | None = None
    for i in picks:
        centre, rotation = poses[i, :3, 3], poses[i, :3, :3]
        lo, hi, found = 0.0, reach, None
        for _ in range(BISECTIONS):
            edge = 0.5 * (lo + hi)
            if best is not None and hi <= best.edge_m:
                break
            q = _cube_poses(model, cell, centre, rotation, q_samples[i], edge, limits)
            if q is None:
                hi = edge
            else:
                lo, found = edge, q
        if found is not None and (best is None or lo > best.edge_m):
            best = IsoCube(centre, lo, rotation, cube_test_positions(centre, lo), found)
    if best is None:
        raise ConfigError(
            f"no reachable, measurable ISO 9283 cube found for {model.description.name} in "
            "this cell; check the cell geometry"
        )
    return best


def make_cube_program(
    model: RobotModel, n: int, config: ProgramConfig, cell: CellConfig
) -> Program:
    """The ISO 9283 pose test as a program of ``n`` visits (``n / 5`` cycles of P1, P5, P4,
    P3, P2), every pose approached from below on every joint, constant load."""
    if n < 10 or n % len(CYCLE_ORDER):
        raise ConfigError(
            f"the iso9283 program needs n = 5 poses x cycles (at least 2 cycles), got n = {n}"
        )
    cube = find_cube(model, cell, config.approach_rad)
    q = np.array([cube.q[name] for name in CYCLE_ORDER] * (n // len(CYCLE_ORDER)))
    approach = np.ones_like(q)
    q_pre = q - approach * config.approach_rad
    times = np.empty((n, 5))
    t, previous = 0.0, q_pre[0]
    for k in range(n):
        times[k] = visit_schedule(t, previous, q_pre[k], config)
        t, previous = times[k, 4], q[k]
    return Program.scheduled(
        q_pre,
        q,
        approach,
        times,
        payload_kg=np.full(n, config.payload_levels_kg[0]),
        air_spring_n=np.full(n, config.air_spring_levels_n[0]),
        phases=(Phase("measure", 0.0, t, config.measure_heating),),
        info=cube.info(),
    )
