"""A reference program for a new set-up: which of a program's poses to measure first.

A day whose tracker was set up anew knows its frames only from its first points. A program's first
poses often lie in one region (UR10 Series A's first 100 span 40-130 deg per joint, condition number
3.2e3), and the robot's local error there tilts any frames fitted on them. The poses are chosen
instead the way calibration poses are (D-optimal design): greedily, each the pose whose measured
position adds most to the log-determinant of the information on the geometry and frames that
calibration identifies, so every prefix of the order is informative too. A model carried onto a new
set-up after 100 of them, chosen among the new series' first 1,000 points, with the geometry fitted
again on them: UR10 B onto A 0.440 mm off A's test points, A onto B 0.448 mm, against 0.659 / 0.599
mm after the series' first 100. Greedy farthest-point order in joint space, which needs no robot,
gave 0.440 / 0.465 mm (BENCHMARKS.md, "A new set-up that starts with a reference program").

>>> import numpy as np
>>> from kinematics.description import load_description
>>> ur10 = load_description("ur10")
>>> q = np.random.default_rng(0).uniform(-3.0, 3.0, (200, 6))
>>> order = reference_order(ur10, q, 40)
>>> int(order[0]), len(set(order.tolist()))
(0, 40)
"""

from __future__ import annotations

import numpy as np

from kinematics.calibration import (
    CalibrationConfig,
    GeometricFrames,
    identifiable,
    rest_observations,
)
from kinematics.description import RobotDescription
from kinematics.errors import ConfigError
from kinematics.identification.fitting import jacobian
from kinematics.model import RobotModel

#: Added to the information matrix (unit-norm parameter columns over the candidates) so that
#: the first poses, which cannot yet determine every parameter, still rank by what they add.
RIDGE = 1e-6


def reference_order(desc: RobotDescription, q: np.ndarray, k: int, first: int = 0) -> np.ndarray:
    """Indices of ``k`` rows of ``q`` (N candidate poses of ``desc``, joint angles in rad) in
    the order to measure them: from row ``first`` (where the robot stands), each next the pose
    whose measured position (three rows of the calibration Jacobian at the nominal) adds most
    to the log-determinant of the information on the identifiable geometry and frames.
    Deterministic; ties go to the earliest row."""
    q = np.asarray(q, dtype=float)
    if q.ndim != 2 or q.shape[1] != desc.n_joints or not len(q):
        raise ConfigError(
            f"reference poses: need joint angles (N, {desc.n_joints}) for {desc.name}, "
            f"got shape {q.shape}"
        )
    if not 1 <= k <= len(q):
        raise ConfigError(f"reference poses: k must be in [1, {len(q)}] poses, got {k}")
    if not 0 <= first < len(q):
        raise ConfigError(f"reference poses: first must be a row in [0, {len(q)}), got {first}")
    rows = position_rows(desc, q)
    information = RIDGE * np.eye(rows.shape[2]) + rows[first].T @ rows[first]
    order, taken = [first], np.zeros(len(q), dtype=bool)
    taken[first] = True
    for _ in range(k - 1):
        projected = rows @ np.linalg.inv(information)
        gain = np.linalg.slogdet(np.eye(3) + projected @ rows.transpose(0, 2, 1))[1]
        nxt = int(np.argmax(np.where(taken, -np.inf, gain)))
        order.append(nxt)
        taken[nxt] = True
        information += rows[nxt].T @ rows[nxt]
    return np.asarray(order)


def program_first(
    desc: RobotDescription, q: np.ndarray, rows: np.ndarray, k: int, window: int
) -> np.ndarray:
    """``rows`` (indices into ``q``, ascending: recorded order) in the order a day that starts
    with a reference program meets them: the first ``k`` of :func:`reference_order` among its
    first ``window`` rows (fewer where the window is shorter), then the rest as recorded."""
    early = np.asarray(rows)[:window]
    first = early[reference_order(desc, np.asarray(q)[early], min(k, len(early)))]
    return np.concatenate([first, np.setdiff1d(rows, first)])


def position_rows(desc: RobotDescription, q: np.ndarray) -> np.ndarray:
    """``(N, 3, p)``: how each pose's position moves with the ``p`` geometry and frame
    parameters calibration identifies from these poses, each parameter's column scaled to unit
    norm over them (so metres and radians weigh alike)."""
    model = RobotModel(desc)
    obs = rest_observations(model, q)
    full = GeometricFrames(desc)
    names = full.parameter_names(desc)
    J = jacobian(model, obs, [(full, np.zeros(len(names)))], 1.0)
    J = J[:, list(identifiable(J, names, CalibrationConfig().rank_rtol).kept_index)]
    J = J / np.linalg.norm(J, axis=0)
    return J.reshape(len(q), 6, -1)[:, :3]
