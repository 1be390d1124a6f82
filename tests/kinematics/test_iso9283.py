"""ISO 9283 pose characteristics on synthetic cycles with hand-computed AP, RP, AD, RD."""

import numpy as np
import pytest

from kinematics.errors import ConfigError
from kinematics.iso9283 import (
    cube_test_positions,
    distance_characteristics,
    group_repeated,
    pose_characteristics,
)

DEG = np.pi / 180.0


def test_ap_rp_of_four_cycles_by_hand():
    # attained positions (m) around a barycentre offset (3, 4, 0) mm from the command (1, 2, 3) m;
    # the four lie 1, 1, 2, 2 mm from the barycentre: l̄ = 1.5, S_l = sqrt(4*0.25/3), RP = l̄ + 3 S_l
    pc = np.array([1.0, 2.0, 3.0])
    bary = pc + np.array([3e-3, 4e-3, 0.0])
    offsets = np.array([[1, 0, 0], [-1, 0, 0], [0, 2, 0], [0, -2, 0]]) * 1e-3
    rot = np.array([[0.1, 0, 0], [0.3, 0, 0], [0.1, 0, 0], [0.3, 0, 0]]) * DEG  # a: 0.1, 0.3 deg
    r = pose_characteristics(bary + offsets, rot, pc)
    assert r.n == 4
    assert r.ap_p_mm == pytest.approx(5.0)  # sqrt(3² + 4²)
    assert (r.ap_x_mm, r.ap_y_mm, r.ap_z_mm) == pytest.approx((3.0, 4.0, 0.0))
    assert r.l_mean_mm == pytest.approx(1.5)
    assert r.s_l_mm == pytest.approx(np.sqrt(1.0 / 3.0))
    assert r.rp_l_mm == pytest.approx(1.5 + 3.0 * np.sqrt(1.0 / 3.0))
    assert r.ap_a_deg == pytest.approx(0.2)  # ā - a_c with a_c = 0
    # S_a = sqrt(4 * 0.1² / 3) deg, RP_a = ±3 S_a
    assert r.rp_a_deg == pytest.approx(3.0 * np.sqrt(0.04 / 3.0))
    assert r.ap_b_deg == r.rp_b_deg == r.ap_c_deg == r.rp_c_deg == 0.0


def test_commanded_orientation_is_subtracted():
    rot = np.full((3, 3), 0.5 * DEG)
    r = pose_characteristics(np.zeros((3, 3)), rot, commanded_rot_rad=np.full(3, 0.2 * DEG))
    assert (r.ap_a_deg, r.ap_b_deg, r.ap_c_deg) == pytest.approx((0.3, 0.3, 0.3))
    assert r.ap_p_mm == 0.0 and r.rp_l_mm == 0.0


def test_distance_accuracy_and_repeatability_by_hand():
    # commanded 100 mm apart along x; attained distances 101, 99, 103 mm: D̄ = 101, AD = +1,
    # S_D = 2, RD = ±6
    pc1, pc2 = np.array([0.1, 0.0, 0.0]), np.zeros(3)
    p2 = np.zeros((3, 3))
    p1 = np.array([[0.101, 0, 0], [0.099, 0, 0], [0.103, 0, 0]])
    d = distance_characteristics(p1, p2, pc1, pc2)
    assert d.n == 3
    assert d.d_c_mm == pytest.approx(100.0)
    assert d.ad_p_mm == pytest.approx(1.0)
    assert d.ad_x_mm == pytest.approx(1.0) and d.ad_y_mm == d.ad_z_mm == 0.0
    assert d.rd_p_mm == pytest.approx(6.0)


def test_bad_cycles_are_one_line_errors():
    with pytest.raises(ConfigError, match="n >= 2"):
        pose_characteristics(np.zeros((1, 3)), np.zeros((1, 3)))
    with pytest.raises(ConfigError, match="orientations"):
        pose_characteristics(np.zeros((3, 3)), np.zeros((2, 3)))
    with pytest.raises(ConfigError, match="finite"):
        pose_characteristics(np.full((3, 3), np.nan), np.zeros((3, 3)))
    with pytest.raises(ConfigError, match="same cycles"):
        distance_characteristics(np.zeros((3, 3)), np.zeros((4, 3)), np.zeros(3), np.ones(3))


def test_cube_test_positions_follow_the_standard():
    pos = cube_test_positions(np.array([1.0, 0.0, 1.0]), 0.5)
    assert set(pos) == {"P1", "P2", "P3", "P4", "P5"}
    assert np.allclose(pos["P1"], [1.0, 0.0, 1.0])
    corner = np.array([1.0, 0.0, 1.0]) + 0.25 * np.array([-1, -1, 1])  # C1
    diagonal = np.linalg.norm(2 * 0.25 * np.array([1, 1, 1]))  # C1 to C7 through the centre
    assert np.linalg.norm(pos["P2"] - corner) == pytest.approx(0.1 * diagonal)
    # all five in one diagonal plane (x - y = const through the centre)
    assert all(abs((p[0] - 1.0) - p[1]) < 1e-12 for p in pos.values())
    with pytest.raises(ConfigError):
        cube_test_positions(np.zeros(3), 0.0)


def test_group_repeated_within_tolerance():
    q = np.array([[0, 0], [1, 1], [0, 1e-7], [1, 1 + 5e-7], [2, 2]], dtype=float)
    groups = group_repeated(q, 1e-6)
    assert [g.tolist() for g in groups] == [[0, 2], [1, 3], [4]]
    assert len(group_repeated(q, 0.0)) == 5


def test_group_repeated_finds_shuffled_cycles_with_encoder_jitter():
    rng = np.random.default_rng(0)
    poses = rng.uniform(-3, 3, (5, 6))
    order = rng.permutation(np.repeat(np.arange(5), 30))
    q = poses[order] + rng.normal(0.0, 1e-6, (150, 6))
    groups = group_repeated(q, 1e-4)
    assert [g.size for g in groups] == [30] * 5
    for g in groups:
        assert np.unique(order[g]).size == 1 and np.all(np.diff(g) > 0)
