"""The robot description value: joints in DH-Hayati form, limits, J2/J3 coupling, tool,
link inertia and sensor ranges (validated on construction).

The loaders (TOML, URDF) live in :mod:`kinematics.description`, which re-exports these; the
URDF reader and the pinocchio model build on this module only.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace

import numpy as np

from kinematics.errors import DescriptionError

COUPLINGS = ("none", "j3_plus_j2")


@dataclass(frozen=True, kw_only=True)
class JointDH:
    """One revolute joint in DH-Hayati form (m, degrees) with optional link inertia."""

    a_m: float
    d_m: float
    alpha_deg: float
    beta_deg: float = 0.0
    offset_deg: float = 0.0
    lower_deg: float = -180.0
    upper_deg: float = 180.0
    mass_kg: float = 0.0
    com_m: tuple[float, float, float] = (0.0, 0.0, 0.0)

    def __post_init__(self) -> None:
        for key in ("a_m", "d_m", "alpha_deg", "beta_deg", "offset_deg", "mass_kg"):
            if not math.isfinite(getattr(self, key)):
                raise DescriptionError(f"joint.{key} must be finite, got {getattr(self, key)}")
        if not self.lower_deg < self.upper_deg:
            raise DescriptionError(
                f"joint limits must satisfy lower_deg < upper_deg, got "
                f"{self.lower_deg} >= {self.upper_deg}"
            )
        if self.mass_kg < 0:
            raise DescriptionError(f"joint.mass_kg must be >= 0, got {self.mass_kg}")


@dataclass(frozen=True, kw_only=True)
class SensorRanges:
    """Declared sensor ranges used for fixed min-max feature scaling."""

    temperature_min_c: float = 0.0
    temperature_max_c: float = 80.0
    deflection_max_rad: float = 0.005

    def __post_init__(self) -> None:
        if not self.temperature_min_c < self.temperature_max_c:
            raise DescriptionError(
                "sensors.temperature_min_c must be < temperature_max_c, got "
                f"{self.temperature_min_c} >= {self.temperature_max_c}"
            )
        if not self.deflection_max_rad > 0:
            raise DescriptionError(
                f"sensors.deflection_max_rad must be > 0, got {self.deflection_max_rad}"
            )


@dataclass(frozen=True, kw_only=True)
class RobotDescription:
    """A serial arm: joints in DH-Hayati form, the J2/J3 coupling and the tool ``T_6_S``."""

    name: str
    joints: tuple[JointDH, ...]
    coupling: str = "none"
    convention: str = "dh_hayati"
    tool: np.ndarray = field(default_factory=lambda: np.eye(4))
    sensors: SensorRanges = field(default_factory=SensorRanges)
    temperature_links: tuple[tuple[str, tuple[int, ...]], ...] = ()

    def __post_init__(self) -> None:
        if self.convention != "dh_hayati":
            raise DescriptionError(f"convention must be 'dh_hayati', got {self.convention!r}")
        if self.coupling not in COUPLINGS:
            raise DescriptionError(f"coupling must be one of {COUPLINGS}, got {self.coupling!r}")
        if self.coupling == "j3_plus_j2" and len(self.joints) < 3:
            raise DescriptionError("coupling 'j3_plus_j2' needs at least 3 joints")
        if not self.joints:
            raise DescriptionError(f"robot {self.name!r} has no joints")
        tool = np.asarray(self.tool, dtype=float)
        if tool.shape != (4, 4) or not np.all(np.isfinite(tool)):
            raise DescriptionError(f"tool must be a finite 4x4 transform, got shape {tool.shape}")
        object.__setattr__(self, "tool", tool)
        for channel, links in self.temperature_links:
            bad = [k for k in links if not 1 <= k <= len(self.joints)]
            if not links or bad:
                raise DescriptionError(
                    f"sensors.temperature_links.{channel}: links must be in 1..{len(self.joints)}"
                    f", got {list(links)}"
                )

    def link_channels(self) -> tuple[tuple[str, ...], ...]:
        """Per joint (its ``a_i``, ``d_i``) the temperature channels that ``[sensors]`` maps to
        it (names without ``temp_``); empty tuples without a map."""
        return tuple(
            tuple(c for c, links in self.temperature_links if i in links)
            for i in range(1, self.n_joints + 1)
        )

    @property
    def n_joints(self) -> int:
        return len(self.joints)

    @property
    def limits_rad(self) -> np.ndarray:
        """Controller joint limits ``(n, 2)`` in rad (lower, upper)."""
        return np.deg2rad([[j.lower_deg, j.upper_deg] for j in self.joints])

    def to_dh(self, q_ctrl: np.ndarray) -> np.ndarray:
        """Controller joint angles ``(..., n)`` -> DH joint variables (coupling applied), rad."""
        q = np.array(q_ctrl, dtype=float, copy=True)
        if self.coupling == "j3_plus_j2":
            q[..., 2] = q[..., 2] + q[..., 1]
        return q

    def with_tool(self, tool: np.ndarray) -> RobotDescription:
        """The same robot with another ``T_6_S``."""
        return replace(self, tool=np.asarray(tool, dtype=float))
