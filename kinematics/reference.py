"""A reference program for a new set-up: which of a program's poses to measure first.

A day whose tracker was set up anew knows its frames only from its first points. A program's first
poses often lie in one region (UR10 Series A's first 100 span 40-130 deg per joint, condition number
3.2e3), and the robot's local error there tilts any frames fitted on them: a model carried from
Series B onto a new set-up was 0.659 mm off A after A's first 100 points, 0.487 mm after 100 poses
chosen here among A's first 1,000 (BENCHMARKS.md, "A new set-up that starts with a reference
program"). Greedy farthest-point order in joint space: each pose is the one farthest from those
before it, so every prefix of the order is spread too, and a line that stops early still has spread
poses. A D-optimal choice on the frames' and geometry's Jacobian gave the same (0.466 against 0.467
mm on A, base alone), for far more work.

>>> import numpy as np
>>> q = np.array([[0.0, 0.0], [0.1, 0.0], [1.0, 1.0], [0.0, 1.0], [1.0, 0.0]])
>>> reference_order(q, 3).tolist()
[0, 2, 3]
"""

from __future__ import annotations

import numpy as np

from kinematics.errors import ConfigError


def reference_order(q: np.ndarray, k: int, first: int = 0) -> np.ndarray:
    """Indices of ``k`` rows of ``q`` (N, n joints; rad) in the order to measure them: from
    row ``first`` (where the robot stands), each next the pose farthest in joint space (rad,
    Euclidean) from all before it. Deterministic; ties go to the earliest row."""
    q = np.asarray(q, dtype=float)
    if q.ndim != 2 or not len(q):
        raise ConfigError(f"reference poses: need joint angles (N, n joints), got shape {q.shape}")
    if not 1 <= k <= len(q):
        raise ConfigError(f"reference poses: k must be in [1, {len(q)}] poses, got {k}")
    if not 0 <= first < len(q):
        raise ConfigError(f"reference poses: first must be a row in [0, {len(q)}), got {first}")
    order = [first]
    distance = np.linalg.norm(q - q[first], axis=1)
    for _ in range(k - 1):
        nxt = int(np.argmax(distance))
        order.append(nxt)
        distance = np.minimum(distance, np.linalg.norm(q - q[nxt], axis=1))
    return np.asarray(order)
