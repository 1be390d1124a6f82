"""Synthetic measured datasets for the learner tests: a Fanuc with known hidden effects.

The "true" robot differs from the nominal description by DH deviations, gravity-driven joint
deflections (seen by the secondary encoders) and thermal growth of link 2; poses carry 15 µm
noise. Small and seeded, so tests are fast and reproducible.
"""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest
import torch

from kinematics.dataset import Dataset, DatasetMeta
from kinematics.description import load_description
from kinematics.effects._base import dh_poses, dh_table
from kinematics.model import RobotModel
from kinematics.transforms import xyz_quat_from_transform

NOISE_M = 15e-6


def make_dataset(n: int, seed: int = 0, q1_range=(-2.0, 2.0)) -> Dataset:
    """``n`` measured points of a perturbed Fanuc M-900iB/700 in the base frame."""
    desc = load_description("fanuc_m900ib700")
    model = RobotModel(desc)
    rng = np.random.default_rng(seed)
    lim = desc.limits_rad
    lo, hi = 0.6 * lim[:, 0], 0.6 * lim[:, 1]
    lo[3], hi[3], lo[5], hi[5] = -np.pi, np.pi, -np.pi, np.pi
    q = rng.uniform(lo, hi, size=(n, 6))
    q[:, 0] = rng.uniform(*q1_range, size=n)
    temps = rng.uniform(18.0, 45.0, size=(n, 2))
    err = np.random.default_rng(1234)  # the same "true" robot for every call
    dh = dh_table(desc).copy()
    dh[:, 0] += err.normal(0, 1e-3, 6)
    dh[:, 1] += err.normal(0, 1e-3, 6)
    dh[:, 4] += err.normal(0, np.deg2rad(0.03), 6)
    tau = model.gravity_torque(q, payload_kg=300.0)
    dtheta = tau / np.array([4e7, 3e7, 2e7, 5e6, 5e6, 2e6])
    dh_pt = np.broadcast_to(dh, (n, 6, 5)).copy()
    dh_pt[:, 1, 0] *= 1.0 + 12e-6 * (temps[:, 0] - 20.0)
    dh_pt[:, 3, 1] *= 1.0 + 12e-6 * (temps[:, 1] - 20.0)
    T = dh_poses(desc.to_dh(q) + dtheta, dh_pt) @ desc.tool[None]
    T[:, :3, 3] += rng.normal(0.0, NOISE_M, size=(n, 3))
    xyz, quat = xyz_quat_from_transform(T)
    table = pd.DataFrame({"t": np.arange(n, dtype=float)})
    for i in range(6):
        table[f"q{i + 1}"] = q[:, i]
    for i in range(6):
        table[f"qs{i + 1}"] = q[:, i] + dtheta[:, i]
    table["temp_link2"] = temps[:, 0]
    table["temp_link4"] = temps[:, 1]
    for k, name in enumerate(("x", "y", "z")):
        table[name] = xyz[:, k]
    for k, name in enumerate(("qx", "qy", "qz", "qw")):
        table[name] = quat[:, k]
    meta = DatasetMeta(robot=desc.name, frame="base", noise_floor_m=NOISE_M * np.sqrt(3))
    return Dataset(table, meta)


@pytest.fixture(autouse=True)
def _one_thread():
    """Every learner test on one torch thread (a loaded machine), the count restored after."""
    threads = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(threads)


@pytest.fixture(scope="session")
def small_ds() -> Dataset:
    return make_dataset(400, seed=0)
