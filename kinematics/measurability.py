"""Which poses the laser tracker can measure: probe facing the tracker, far enough away.

A 6-D probe (T-Mac) is visible when the angle between its z axis and the line from the probe
to the tracker (at the origin of ``{W}``) is at most 45° and the tracker–probe distance is at
least 1.5 m (DESIGN.md, "Measurement cell").

>>> import numpy as np
>>> from kinematics.transforms import transform_from_xyz_rpy
>>> T_W_S = transform_from_xyz_rpy([2.0, 0.0, 0.0], [0.0, -np.pi / 2, 0.0])[None]
>>> m = measurability_from_poses(T_W_S)
>>> m.visible.tolist(), round(float(np.rad2deg(m.angle_rad[0])), 6), m.distance_m.tolist()
([True], 0.0, [2.0])
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from kinematics.errors import ConfigError
from kinematics.model import RobotModel


@dataclass(frozen=True, kw_only=True)
class MeasurabilityConfig:
    """Visibility thresholds of the tracker: incidence angle (degrees) and distance (m)."""

    max_angle_deg: float = 45.0
    min_distance_m: float = 1.5

    def __post_init__(self) -> None:
        if not 0.0 < self.max_angle_deg <= 180.0:
            raise ConfigError(f"max_angle_deg must be in (0, 180], got {self.max_angle_deg}")
        if not self.min_distance_m >= 0.0:
            raise ConfigError(f"min_distance_m must be >= 0, got {self.min_distance_m}")


@dataclass(frozen=True, kw_only=True)
class Measurability:
    """Per pose: visible or not, the incidence angle (rad) and the tracker distance (m)."""

    visible: np.ndarray
    angle_rad: np.ndarray
    distance_m: np.ndarray


def measurability_from_poses(
    T_W_S: np.ndarray, config: MeasurabilityConfig | None = None
) -> Measurability:
    """Visibility of probe poses ``T_W_S`` ``(N, 4, 4)`` given in the tracker frame."""
    config = config or MeasurabilityConfig()
    T = np.asarray(T_W_S, dtype=float).reshape(-1, 4, 4)
    to_tracker = -T[:, :3, 3]
    distance = np.linalg.norm(to_tracker, axis=1)
    cos = np.einsum("ni,ni->n", T[:, :3, 2], to_tracker) / np.maximum(distance, 1e-12)
    angle = np.arccos(np.clip(cos, -1.0, 1.0))
    visible = (angle <= np.deg2rad(config.max_angle_deg)) & (distance >= config.min_distance_m)
    return Measurability(visible=visible, angle_rad=angle, distance_m=distance)


def measurability(
    model: RobotModel,
    q: np.ndarray,
    T_W_0: np.ndarray,
    T_6_S: np.ndarray,
    config: MeasurabilityConfig | None = None,
) -> Measurability:
    """Visibility of the probe at joint configurations ``q`` ``(N, n)`` (rad, controller).

    ``T_W_S = T_W_0 · T_0_6(q) · T_6_S`` with the nominal flange FK of ``model``.
    """
    flange = model.fk(np.atleast_2d(q), frame="flange")
    T_W_S = np.asarray(T_W_0, dtype=float)[None] @ flange @ np.asarray(T_6_S, dtype=float)[None]
    return measurability_from_poses(T_W_S, config)
