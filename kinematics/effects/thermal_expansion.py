"""``thermal_expansion``: link lengths grow with their temperature above the reference.

For joint ``i``: ``da_i = a_i k_i (T_i - T_ref)`` and ``dd_i = d_i k_i (T_i - T_ref)``, with
``k_i`` the expansion coefficient (1/K, steel 11.5e-6) and ``T_i`` the mean of the sensors that
``link_sensors`` maps to link ``i``. A robot with one thermometer lets it drive every link
(:meth:`ThermalExpansion.single`, and the fallback when the mapped sensors are absent and there
is exactly one temperature). Parameters ``k{i}_per_K``; linear, zero = no effect.

With ``terms`` instead, each term ``(link, channels)`` is one parameter: joint ``link``'s
lengths grow by ``k`` times the mean of ``channels`` above the reference. A description's
``[sensors]`` map gives one term per mapped link; without a map the gap workflow forms the
terms from the data (:mod:`kinematics.gap.formed`), one channel per term, named
``k{link}_{channel}_per_K``.
"""

from __future__ import annotations

import numpy as np

from kinematics.dataset import temperature_column
from kinematics.description import RobotDescription
from kinematics.effects._base import Conditions, Effect, Perturbation
from kinematics.errors import ConfigError
from kinematics.model import RobotModel

#: The 14 structure sensors of the reference cell (motors, gears, castings), then the ambient.
STRUCTURE_SENSORS = (
    "j1_motor",
    "j1_gear",
    "j2_motor",
    "j2_gear",
    "j3_motor",
    "j3_gear",
    "j4_motor",
    "j5_motor",
    "j6_motor",
    "base",
    "lower_arm",
    "upper_arm_rear",
    "upper_arm_front",
    "wrist",
)
AMBIENT_SENSOR = "ambient"
REFERENCE_SENSORS = (*STRUCTURE_SENSORS, AMBIENT_SENSOR)

#: Which sensors measure which link (joint i's a_i, d_i) on the reference cell.
DEFAULT_LINK_SENSORS: tuple[tuple[str, ...], ...] = (
    ("base", "j1_gear"),
    ("lower_arm", "j2_gear"),
    ("j3_gear", "j3_motor"),
    ("upper_arm_rear", "upper_arm_front"),
    ("wrist",),
    ("wrist", "j6_motor"),
)


class ThermalExpansion(Effect):
    """Thermal growth of the DH lengths ``a_i`` and ``d_i``."""

    name = "thermal_expansion"

    def __init__(
        self,
        link_sensors: tuple[tuple[str, ...], ...] = DEFAULT_LINK_SENSORS,
        t_ref_c: float = 20.0,
        terms: tuple[tuple[int, tuple[str, ...]], ...] = (),
    ) -> None:
        if not np.isfinite(t_ref_c):
            raise ConfigError(f"thermal_expansion.t_ref_c must be finite, got {t_ref_c}")
        if any(not names for names in link_sensors):
            raise ConfigError(f"every link needs at least one sensor, got {link_sensors}")
        self.link_sensors = tuple(tuple(names) for names in link_sensors)
        self.t_ref_c = float(t_ref_c)
        self.terms = tuple((int(link), tuple(chs)) for link, chs in terms)
        if any(link < 1 or not chs for link, chs in self.terms):
            raise ConfigError(f"thermal_expansion.terms need links >= 1 and channels, got {terms}")

    @classmethod
    def single(cls, sensor: str, n_joints: int = 6, t_ref_c: float = 20.0) -> ThermalExpansion:
        """One thermometer ``sensor`` drives every link."""
        return cls(link_sensors=((sensor,),) * n_joints, t_ref_c=t_ref_c)

    def options(self) -> dict:
        if self.terms:
            return {"terms": [[k, list(c)] for k, c in self.terms], "t_ref_c": self.t_ref_c}
        return {"link_sensors": [list(s) for s in self.link_sensors], "t_ref_c": self.t_ref_c}

    def needs(self, model: RobotModel, cond: Conditions) -> str | None:
        if cond.temperatures is None or not cond.temperature_names:
            return (
                f"needs temperature channels ({temperature_column('<name>')} columns); "
                "the dataset has none"
            )
        return None

    def parameter_names(self, desc: RobotDescription) -> tuple[str, ...]:
        if self.terms:
            return tuple(
                f"k{k}_{c[0]}_per_K" if len(c) == 1 else f"k{k}_per_K" for k, c in self.terms
            )
        return tuple(f"k{i}_per_K" for i in range(1, desc.n_joints + 1))

    def term_temperatures(self, cond: Conditions) -> np.ndarray:
        """Temperatures (N, terms) °C of each term: the mean of its channels."""
        if cond.temperatures is None:
            raise ConfigError("thermal_expansion needs conditions.temperatures, got None")
        names = tuple(cond.temperature_names)
        missing = sorted({c for _, chs in self.terms for c in chs} - set(names))
        if missing:
            raise ConfigError(f"thermal_expansion needs channel(s) {missing}, got {list(names)}")
        temps = np.asarray(cond.temperatures, dtype=float)
        return np.stack(
            [temps[:, [names.index(c) for c in chs]].mean(axis=1) for _, chs in self.terms], 1
        )

    def link_temperatures(self, cond: Conditions, n_joints: int) -> np.ndarray:
        """Temperatures (N, n) °C of each link, from the mapped sensors (or the single one)."""
        if cond.temperatures is None:
            raise ConfigError("thermal_expansion needs conditions.temperatures, got None")
        temps = np.asarray(cond.temperatures, dtype=float)
        names = tuple(cond.temperature_names)
        if len(self.link_sensors) < n_joints:
            raise ConfigError(
                f"thermal_expansion maps {len(self.link_sensors)} links, robot has {n_joints}"
            )
        out = np.empty((cond.n_points, n_joints))
        for i, sensors in enumerate(self.link_sensors[:n_joints]):
            cols = [names.index(s) for s in sensors if s in names]
            if not cols and len(names) == 1:
                cols = [0]
            if not cols:
                raise ConfigError(
                    f"thermal_expansion: link {i + 1} needs sensor(s) {list(sensors)}, "
                    f"got {list(names)}"
                )
            out[:, i] = temps[:, cols].mean(axis=1)
        return out

    def perturbation(self, model: RobotModel, params: np.ndarray, cond: Conditions) -> Perturbation:
        desc = model.description
        params = self.checked(desc, params)
        out = Perturbation.zero(cond.n_points, desc.n_joints)
        if self.terms and np.any(params != 0):
            links = np.array([k - 1 for k, _ in self.terms])
            if links.max() >= desc.n_joints:
                raise ConfigError(f"thermal_expansion.terms name link {links.max() + 1}")
            grow = params[None] * (self.term_temperatures(cond) - self.t_ref_c)
            lengths = np.array([[j.a_m, j.d_m] for j in desc.joints])[links]
            np.add.at(out.ddh[:, :, :2], (slice(None), links), grow[:, :, None] * lengths[None])
        elif np.any(params != 0):
            strain = params[None] * (self.link_temperatures(cond, desc.n_joints) - self.t_ref_c)
            lengths = np.array([[j.a_m, j.d_m] for j in desc.joints])
            out.ddh[:, :, :2] = strain[:, :, None] * lengths[None]
        return out
