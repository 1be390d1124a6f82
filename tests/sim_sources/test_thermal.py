"""Temperatures of the simulated cell: cold start, first-order lag, bounded warm-up rise."""

import numpy as np
import pytest

from kinematics.errors import ConfigError
from sim_sources.thermal import ThermalConfig, ThermalHistory


def test_constant_heating_follows_the_first_order_lag():
    config = ThermalConfig(ambient_swing_k=0.0)
    h = ThermalHistory.compute(config, np.array([0.0]), np.array([1.0]), duration_s=7200.0)
    t = np.array([0.0, 600.0, 1800.0, 7200.0])
    temps = h.at(t)
    for k, (gain, tau) in enumerate(zip(config.gains_k, config.time_constants_s, strict=True)):
        np.testing.assert_allclose(temps[:, k], 20.0 + gain * (1 - np.exp(-t / tau)), atol=1e-9)
    np.testing.assert_allclose(temps[:, -1], 20.0)


def test_warm_up_rises_at_most_55_kelvin_and_cools_down_again():
    config = ThermalConfig()
    h = ThermalHistory.compute(config, np.array([0.0, 3600.0]), np.array([1.0, 0.0]), 4 * 3600.0)
    rise = h.temps_c[:, :-1] - h.temps_c[:, -1:]
    assert 50.0 < rise.max() <= 55.0
    assert np.all(h.at(np.array([4 * 3600.0]))[0, :-1] < h.at(np.array([3600.0]))[0, :-1])
    assert h.sensors[-1] == "ambient" and len(h.sensors) == 15


def test_bad_config_names_the_value():
    with pytest.raises(ConfigError, match="gains_k must be in"):
        ThermalConfig(gains_k=(60.0,) * 14)
    with pytest.raises(ConfigError, match="15 sensors need 14 gains"):
        ThermalConfig(gains_k=(1.0,))
