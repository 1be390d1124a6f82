"""Region statistics against the noise floor, and the noise-floor estimate."""

import numpy as np
import pytest

from kinematics.effects import Conditions
from kinematics.gap.regions import (
    MAXWELL_MEAN,
    NoiseFloor,
    estimate_noise_floor,
    region_labels,
    region_stats,
)
from kinematics.identification.conditions import Observations

SIGMA = 20e-6


def observations(n, rng, temperatures=True):
    cond = Conditions(
        q=rng.uniform(-2, 2, (n, 6)),
        t=np.arange(n, dtype=float),
        temperatures=rng.uniform(20, 40, (n, 2)) if temperatures else None,
        temperature_names=("a", "b") if temperatures else (),
        approach=np.sign(rng.normal(size=(n, 6))),
    )
    return Observations(cond=cond, T_measured=np.tile(np.eye(4), (n, 1, 1)), T_W_0=np.eye(4))


@pytest.fixture
def case():
    rng = np.random.default_rng(0)
    n = 2000
    obs = observations(n, rng)
    xyz = rng.normal(size=(n, 3))
    labels = region_labels(obs, xyz, deflection=rng.normal(size=(n, 6)) * 1e-5)
    floor = NoiseFloor(mean_m=MAXWELL_MEAN * SIGMA, source="test")
    return rng, n, xyz, labels, floor


def test_families_and_bins(case):
    _, n, _, labels, _ = case
    assert {"octant", "q1", "q6", "time", "temperature", "load", "approach3"} <= labels.keys()
    assert len(np.unique(labels["octant"])) == 8
    assert len(np.unique(labels["time"])) == 4 and len(np.unique(labels["q2"])) == 3
    assert all(len(v) == n for v in labels.values())


def test_pure_noise_flags_nothing(case):
    rng, n, _, labels, floor = case
    stats = region_stats(rng.normal(0, SIGMA, (n, 3)), labels, floor)
    assert not any(s.significant for s in stats)
    assert stats[0].region == "all points" and 0.9 < stats[0].ratio_to_floor < 1.1


def test_a_biased_octant_is_flagged_alone(case):
    rng, n, xyz, labels, floor = case
    e = rng.normal(0, SIGMA, (n, 3))
    octant = labels["octant"] == "x+y+z+"
    e[octant, 2] += 3 * SIGMA
    flagged = {(s.family, s.region) for s in region_stats(e, labels, floor) if s.significant}
    assert ("octant", "x+y+z+") in flagged
    assert not any(f == "octant" and r != "x+y+z+" for f, r in flagged)


def test_noise_floor_estimate_from_repeated_poses():
    rng = np.random.default_rng(1)
    q = np.repeat(rng.uniform(-2, 2, (500, 6)), 2, axis=0)
    systematic = np.repeat(rng.normal(0, 1e-3, (500, 3)), 2, axis=0)
    floor = estimate_noise_floor(q, systematic + rng.normal(0, SIGMA, (1000, 3)))
    assert floor.sigma_m == pytest.approx(SIGMA, rel=0.15)
    assert "estimated" in floor.source
