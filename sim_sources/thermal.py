"""Temperatures of the simulated cell: 14 structure sensors and the ambient.

Each structure sensor follows a first-order thermal lag towards ``ambient + gain * heating``,
where ``heating`` in [0, 1] is the program's activity (1 in warm-up phases, 0 when idle):
``dT/dt = (ambient + gain h(t) - T) / tau``. The ambient swings slowly around its mean. The
history is integrated once on a fine grid (exact for inputs held over a step, via
``scipy.signal.lfilter``) from a cold start and read at any time by linear interpolation.

>>> import numpy as np
>>> h = ThermalHistory.compute(ThermalConfig(), np.array([0.0, 3600.0]), np.array([1.0, 0.0]),
...                            duration_s=7200.0)
>>> bool(h.at(np.array([3600.0]))[0, 2] > 60.0)
True
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.signal import lfilter

from kinematics.effects.thermal_expansion import REFERENCE_SENSORS
from kinematics.errors import ConfigError

_DEFAULT_GAINS_K = (
    42.0,
    30.0,
    55.0,
    38.0,
    50.0,
    35.0,
    40.0,
    36.0,
    32.0,
    8.0,
    22.0,
    25.0,
    20.0,
    28.0,
)
_DEFAULT_TAUS_S = (
    900.0, 1500.0, 900.0, 1500.0, 900.0, 1500.0, 800.0, 700.0, 700.0,
    3600.0, 2400.0, 2400.0, 2000.0, 1200.0,
)  # fmt: skip


@dataclass(frozen=True, kw_only=True)
class ThermalConfig:
    """Sensor names (structure sensors first, the ambient last), gains (K at full heating) and
    time constants (s) per structure sensor, and the ambient (°C, K, s)."""

    sensors: tuple[str, ...] = REFERENCE_SENSORS
    gains_k: tuple[float, ...] = _DEFAULT_GAINS_K
    time_constants_s: tuple[float, ...] = _DEFAULT_TAUS_S
    ambient_c: float = 20.0
    ambient_swing_k: float = 1.5
    ambient_period_s: float = 86400.0
    step_s: float = 1.0

    def __post_init__(self) -> None:
        n = len(self.sensors) - 1
        if n < 0 or len(self.gains_k) != n or len(self.time_constants_s) != n:
            raise ConfigError(
                f"thermal: {len(self.sensors)} sensors need {n} gains and time constants, got "
                f"{len(self.gains_k)} and {len(self.time_constants_s)}"
            )
        if any(g < 0 or g > 55.0 for g in self.gains_k):
            raise ConfigError(f"thermal.gains_k must be in [0, 55] K, got {self.gains_k}")
        if any(tau <= 0 for tau in self.time_constants_s):
            raise ConfigError(f"thermal.time_constants_s must be > 0, got {self.time_constants_s}")
        if not 0 < self.step_s <= 60.0:
            raise ConfigError(f"thermal.step_s must be in (0, 60] s, got {self.step_s}")


@dataclass(frozen=True)
class ThermalHistory:
    """Temperatures ``temps_c`` (K, sensors) °C on the grid ``t_s`` (K,) s."""

    sensors: tuple[str, ...]
    t_s: np.ndarray
    temps_c: np.ndarray

    @classmethod
    def compute(
        cls,
        config: ThermalConfig,
        heat_start_s: np.ndarray,
        heat_level: np.ndarray,
        duration_s: float,
    ) -> ThermalHistory:
        """Integrate from a cold start for a heating schedule: ``heat_level[k]`` (0..1) holds
        from ``heat_start_s[k]`` (s, ascending, first 0) until the next start."""
        t = np.arange(0.0, duration_s + 2 * config.step_s, config.step_s)
        idx = np.searchsorted(np.asarray(heat_start_s, dtype=float), t, side="right") - 1
        heat = np.asarray(heat_level, dtype=float)[np.clip(idx, 0, None)]
        ambient = config.ambient_c + config.ambient_swing_k * np.sin(
            2 * np.pi * t / config.ambient_period_s
        )
        temps = np.empty((t.size, len(config.sensors)))
        temps[:, -1] = ambient
        for k, (gain, tau) in enumerate(zip(config.gains_k, config.time_constants_s, strict=True)):
            a = np.exp(-config.step_s / tau)
            target = ambient + gain * heat
            rise, _ = lfilter([0.0, 1.0 - a], [1.0, -a], target, zi=[ambient[0]])
            temps[:, k] = rise
        return cls(tuple(config.sensors), t, temps)

    def at(self, t_s: np.ndarray) -> np.ndarray:
        """Temperatures (N, sensors) °C at times ``t_s`` (N,) s, linearly interpolated."""
        t_s = np.asarray(t_s, dtype=float)
        return np.stack([np.interp(t_s, self.t_s, col) for col in self.temps_c.T], axis=-1)
