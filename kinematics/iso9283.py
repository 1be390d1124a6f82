"""ISO 9283:1998 pose characteristics: pose accuracy AP, pose repeatability RP, distance
accuracy AD and distance repeatability RD (pure numpy, no I/O).

A pose test (ISO 9283 clause 7.2) commands the same pose ``n`` times (cycles; the standard asks
for 30), approached from the same direction, and measures the attained pose each time. The
standard's units (clause 4): lengths in mm, angles in degrees. Here attained and commanded
positions come in as metres and are reported in mm; orientations come in as the small rotation
of the attained pose against the commanded one, ``vec(R_attained R_c^T)`` (rad, about the base
axes x, y, z), which to first order is the difference of the standard's angles ``a, b, c``
(rotations about x, y, z) to the commanded ones, and are reported in degrees.

>>> import numpy as np
>>> r = pose_characteristics(np.array([[1e-3, 0, 0], [3e-3, 0, 0]]), np.zeros((2, 3)))
>>> round(r.ap_p_mm, 6), round(r.rp_l_mm, 6)
(2.0, 1.0)
"""

from __future__ import annotations

from dataclasses import asdict, dataclass

import numpy as np

from kinematics.errors import ConfigError

#: Cycles the standard asks for at each test pose (ISO 9283 clause 7.2.1).
STANDARD_CYCLES = 30
#: Share of the plane's diagonal between a corner of the cube's diagonal plane and the test
#: pose near it (ISO 9283 clause 6.8: P2-P5 at (10 ± 2) % of the diagonal from the corners).
CORNER_SHARE = 0.10
DEG_PER_RAD = 180.0 / np.pi


@dataclass(frozen=True, kw_only=True)
class _Characteristics:
    """ISO 9283 characteristics measured over ``n`` cycles; ``to_dict`` for reports."""

    n: int

    def to_dict(self) -> dict[str, float | int]:
        return asdict(self)


@dataclass(frozen=True, kw_only=True)
class PoseCharacteristics(_Characteristics):
    """AP and RP of one test pose (ISO 9283 clause 7.2), mm and degrees.

    ``ap_p_mm`` positional pose accuracy AP_P, the distance from the barycentre of the attained
    positions to the commanded position; ``ap_x_mm, ap_y_mm, ap_z_mm`` its components
    (``x̄ - x_c`` ...); ``ap_a_deg, ap_b_deg, ap_c_deg`` orientation pose accuracy
    (``ā - a_c`` ...); ``rp_l_mm`` positional pose repeatability RP_l = l̄ + 3 S_l, the radius
    of the sphere around the barycentre; ``rp_a_deg, rp_b_deg, rp_c_deg`` orientation pose
    repeatability ±3 S_a (the half-width, as the standard writes ``±``); ``l_mean_mm`` l̄ and
    ``s_l_mm`` S_l; ``n`` the cycles.
    """

    ap_p_mm: float
    ap_x_mm: float
    ap_y_mm: float
    ap_z_mm: float
    ap_a_deg: float
    ap_b_deg: float
    ap_c_deg: float
    rp_l_mm: float
    l_mean_mm: float
    s_l_mm: float
    rp_a_deg: float
    rp_b_deg: float
    rp_c_deg: float


@dataclass(frozen=True, kw_only=True)
class DistanceCharacteristics(_Characteristics):
    """AD and RD between two test poses (ISO 9283 clause 7.4), mm.

    ``ad_p_mm`` distance accuracy AD_P = D̄ - D_c (signed: attained distances longer than the
    commanded one are positive); ``ad_x_mm, ad_y_mm, ad_z_mm`` its components
    (``D̄_x - D_cx`` ... with ``D_x = x_1 - x_2``); ``rd_p_mm`` distance repeatability
    ±3 S_D (half-width); ``d_c_mm`` the commanded distance D_c; ``n`` the cycles.
    """

    d_c_mm: float
    ad_p_mm: float
    ad_x_mm: float
    ad_y_mm: float
    ad_z_mm: float
    rd_p_mm: float


def _cycles(name: str, a: np.ndarray, width: int = 3) -> np.ndarray:
    a = np.asarray(a, dtype=float)
    if a.ndim != 2 or a.shape[1] != width or a.shape[0] < 2 or not np.isfinite(a).all():
        raise ConfigError(f"{name} must be finite (n >= 2, {width}), got shape {a.shape}")
    return a


def pose_characteristics(
    attained_m: np.ndarray,
    attained_rot_rad: np.ndarray,
    commanded_m: np.ndarray | None = None,
    commanded_rot_rad: np.ndarray | None = None,
) -> PoseCharacteristics:
    """AP and RP (ISO 9283 7.2.1, 7.2.2) of one pose from ``n`` attained positions ``(n, 3)`` m
    and orientations ``(n, 3)`` rad about x, y, z, against the commanded position ``(3,)`` m
    and orientation ``(3,)`` rad (both zero by default: attained values already relative).

    AP_P = sqrt((x̄-x_c)² + (ȳ-y_c)² + (z̄-z_c)²); AP_a = ā - a_c (b, c alike);
    RP_l = l̄ + 3 S_l with l_j = |P_j - barycentre| and S_l = sqrt(Σ(l_j - l̄)² / (n-1));
    RP_a = ±3 S_a with S_a = sqrt(Σ(a_j - ā)² / (n-1)).
    """
    p = _cycles("attained positions", attained_m)
    r = _cycles("attained orientations", attained_rot_rad)
    if len(r) != len(p):
        raise ConfigError(f"{len(p)} attained positions but {len(r)} orientations")
    pc = np.zeros(3) if commanded_m is None else np.asarray(commanded_m, dtype=float)
    rc = np.zeros(3) if commanded_rot_rad is None else np.asarray(commanded_rot_rad, dtype=float)
    bary = p.mean(axis=0)
    ap = (bary - pc) * 1e3
    ap_rot = (r.mean(axis=0) - rc) * DEG_PER_RAD
    l_mm = np.linalg.norm(p - bary, axis=1) * 1e3
    s_l = float(l_mm.std(ddof=1))
    s_rot = r.std(axis=0, ddof=1) * DEG_PER_RAD
    return PoseCharacteristics(
        n=len(p),
        ap_p_mm=float(np.linalg.norm(ap)),
        ap_x_mm=float(ap[0]),
        ap_y_mm=float(ap[1]),
        ap_z_mm=float(ap[2]),
        ap_a_deg=float(ap_rot[0]),
        ap_b_deg=float(ap_rot[1]),
        ap_c_deg=float(ap_rot[2]),
        rp_l_mm=float(l_mm.mean() + 3.0 * s_l),
        l_mean_mm=float(l_mm.mean()),
        s_l_mm=s_l,
        rp_a_deg=float(3.0 * s_rot[0]),
        rp_b_deg=float(3.0 * s_rot[1]),
        rp_c_deg=float(3.0 * s_rot[2]),
    )


def distance_characteristics(
    attained_1_m: np.ndarray,
    attained_2_m: np.ndarray,
    commanded_1_m: np.ndarray,
    commanded_2_m: np.ndarray,
) -> DistanceCharacteristics:
    """AD and RD (ISO 9283 7.4) of the distance between two poses, from their attained
    positions ``(n, 3)`` m in the same cycles (row j of each from cycle j) and their commanded
    positions ``(3,)`` m.

    D_j = |P1_j - P2_j|, D_c = |Pc1 - Pc2|, AD_P = D̄ - D_c, AD_x = D̄_x - D_cx (D_x = x1 - x2),
    RD_P = ±3 S_D with S_D = sqrt(Σ(D_j - D̄)² / (n-1)).
    """
    p1 = _cycles("attained positions of pose 1", attained_1_m)
    p2 = _cycles("attained positions of pose 2", attained_2_m)
    if len(p1) != len(p2):
        raise ConfigError(f"distance needs the same cycles at both poses, got {len(p1)}, {len(p2)}")
    dc = np.asarray(commanded_1_m, dtype=float) - np.asarray(commanded_2_m, dtype=float)
    d_xyz = p1 - p2
    d = np.linalg.norm(d_xyz, axis=1) * 1e3
    dc_mm = float(np.linalg.norm(dc) * 1e3)
    ad_xyz = (d_xyz.mean(axis=0) - dc) * 1e3
    return DistanceCharacteristics(
        n=len(d),
        d_c_mm=dc_mm,
        ad_p_mm=float(d.mean() - dc_mm),
        ad_x_mm=float(ad_xyz[0]),
        ad_y_mm=float(ad_xyz[1]),
        ad_z_mm=float(ad_xyz[2]),
        rd_p_mm=float(3.0 * d.std(ddof=1)),
    )


def cube_test_positions(centre_m: np.ndarray, edge_m: float) -> dict[str, np.ndarray]:
    """The five test positions P1-P5 (m) of the ISO 9283 cube (clause 6.8) of ``edge_m``
    centred at ``centre_m``, axes parallel to the base frame.

    The measuring plane is the diagonal plane C1-C2-C7-C8 through the cube's edges
    ``(-,-,·)`` and ``(+,+,·)``; P1 is the centre, P2-P5 lie on the plane's diagonals at
    ``CORNER_SHARE`` of the diagonal's length from the plane corners C1 ``(-,-,+)``,
    C2 ``(+,+,+)``, C7 ``(+,+,-)``, C8 ``(-,-,-)``, in that order.
    """
    if not (np.isfinite(edge_m) and edge_m > 0):
        raise ConfigError(f"cube edge must be > 0 m, got {edge_m}")
    c = np.asarray(centre_m, dtype=float)
    h = 0.5 * edge_m
    corners = np.array([[-h, -h, h], [h, h, h], [h, h, -h], [-h, -h, -h]])
    # a corner moved 10 % of the plane diagonal towards the opposite corner: corner * (1 - 0.2)
    out = {"P1": c.copy()}
    for k, corner in enumerate(corners):
        out[f"P{k + 2}"] = c + corner * (1.0 - 2.0 * CORNER_SHARE)
    return out


def group_repeated(q: np.ndarray, tolerance_rad: float = 1e-6) -> list[np.ndarray]:
    """Rows of commanded joint angles ``q`` (N, n) rad that command the same pose: groups of
    row indices (in order of first appearance) whose angles all lie within ``tolerance_rad``
    of the group's first row; single rows are groups of one."""
    q = np.asarray(q, dtype=float)
    if q.ndim != 2 or not np.isfinite(q).all():
        raise ConfigError(f"commanded joints must be a finite (N, n) array, got shape {q.shape}")
    if not tolerance_rad >= 0:
        raise ConfigError(f"pose tolerance must be >= 0 rad, got {tolerance_rad}")
    label = np.full(len(q), -1)
    groups: list[np.ndarray] = []
    order = np.argsort(q[:, 0], kind="stable")  # candidates: rows this close in joint 1
    first = q[order, 0]
    for i in range(len(q)):
        if label[i] >= 0:
            continue
        lo = np.searchsorted(first, q[i, 0] - tolerance_rad, "left")
        hi = np.searchsorted(first, q[i, 0] + tolerance_rad, "right")
        near = order[lo:hi]
        same = np.sort(
            near[(label[near] < 0) & (np.abs(q[near] - q[i]).max(axis=1) <= tolerance_rad)]
        )
        label[same] = len(groups)
        groups.append(same)
    return groups
