"""Where model and measurement disagree: position residuals by region against the noise floor.

Regions: workspace octants (about the median tool position), joint-angle terciles, time
quartiles, temperature terciles (mean sensor), load terciles (``|qs - q|``) and the approach
direction per joint. A region is flagged when its mean position error exceeds the noise floor:
a one-sided one-sample t-test of the error norms against the floor (no assumption on the
noise's shape or anisotropy), at a level Bonferroni-corrected over all regions.

The noise floor is the mean position-error norm that noise alone gives (the simulator's
``noise_floor_m``); for isotropic Gaussian noise ``mean |e| = 2 sigma sqrt(2 / pi)``.
"""

from __future__ import annotations

import re
from dataclasses import dataclass

import numpy as np
from scipy.spatial import cKDTree
from scipy.stats import chi2, ttest_1samp

from kinematics.error_stats import ErrorStats
from kinematics.identification.conditions import Observations

#: mean |e| / sigma for an isotropic 3-D Gaussian (Maxwell distribution).
MAXWELL_MEAN = 2.0 * np.sqrt(2.0 / np.pi)


@dataclass(frozen=True, kw_only=True)
class NoiseFloor:
    """The noise floor (mean position-error norm, m) and where it came from."""

    mean_m: float
    source: str

    @property
    def sigma_m(self) -> float:
        """Per-axis standard deviation (m) of isotropic noise with this mean norm."""
        return self.mean_m / MAXWELL_MEAN


def estimate_noise_floor(q: np.ndarray, residual_m: np.ndarray) -> NoiseFloor:
    """Noise floor from nearest neighbours in joint space: their residual differences hold
    twice the noise variance plus what the model error differs by (an upper bound)."""
    _, idx = cKDTree(q).query(q, k=2)
    own = np.arange(len(q))
    neighbour = np.where(idx[:, 0] == own, idx[:, 1], idx[:, 0])
    diff = residual_m - residual_m[neighbour]
    sigma = np.sqrt(np.median(np.sum(diff**2, axis=1)) / chi2.ppf(0.5, 3) / 2.0)
    return NoiseFloor(
        mean_m=float(MAXWELL_MEAN * sigma),
        source="estimated from nearest-neighbour residual differences (an upper bound)",
    )


@dataclass(frozen=True, kw_only=True)
class RegionStat(ErrorStats):
    """Residual statistics of one region against the noise floor."""

    family: str
    region: str
    ratio_to_floor: float
    p_value: float
    significant: bool

    #: The keys of a region in ``robocal gap --json``.
    KEYS = (
        "family",
        "region",
        "n",
        "mean_mm",
        "rms_mm",
        "max_mm",
        "ratio_to_floor",
        "p_value",
        "significant",
    )


def region_labels(obs: Observations, tool_xyz_m: np.ndarray, deflection: np.ndarray | None):
    """``{family: (labels (N,) of str)}`` for every region family the data supports."""
    out: dict[str, np.ndarray] = {}
    centre = np.median(tool_xyz_m, axis=0)
    signs = np.where(tool_xyz_m >= centre, "+", "-")
    out["octant"] = np.array([f"x{a}y{b}z{c}" for a, b, c in signs])
    q = np.asarray(obs.cond.q)
    for i in range(q.shape[1]):
        out[f"q{i + 1}"] = _bins(np.rad2deg(q[:, i]), 3, f"q{i + 1}", "deg")
    out["time"] = _bins(np.asarray(obs.cond.t), 4, "t", "s")
    if obs.cond.temperatures is not None:
        mean_t = np.asarray(obs.cond.temperatures).mean(axis=1)
        out["temperature"] = _bins(mean_t, 3, "T_mean", "C")
    if deflection is not None:
        out["load"] = _bins(np.linalg.norm(deflection, axis=1) * 1e6, 3, "|qs-q|", "urad")
    if obs.cond.approach is not None:
        for i in range(q.shape[1]):
            out[f"approach{i + 1}"] = np.where(
                np.asarray(obs.cond.approach)[:, i] > 0, f"j{i + 1} up", f"j{i + 1} down"
            )
    return out


def _bins(values: np.ndarray, k: int, name: str, unit: str) -> np.ndarray:
    edges = np.unique(np.quantile(values, np.linspace(0, 1, k + 1)))
    if edges.size < 2:
        return np.full(values.shape, f"{name} = {values[0]:.4g} {unit}")
    idx = np.clip(np.searchsorted(edges, values, side="right") - 1, 0, edges.size - 2)
    labels = [
        f"{name} in [{lo:.4g}, {hi:.4g}] {unit}"
        for lo, hi in zip(edges[:-1], edges[1:], strict=True)
    ]
    return np.array(labels)[idx]


def _order(label: str) -> tuple:
    """Sort key: bins by their lower edge, other labels alphabetically."""
    match = re.search(r"\[(-?[0-9.]+(?:e[-+]?[0-9]+)?),", label)
    return (0, float(match.group(1)), label) if match else (1, 0.0, label)


def region_stats(
    residual_m: np.ndarray,
    labels: dict[str, np.ndarray],
    floor: NoiseFloor,
    level: float = 0.01,
) -> list[RegionStat]:
    """Statistics of every region (``residual_m`` (N, 3) position errors); Bonferroni over all."""
    norm = np.linalg.norm(residual_m, axis=1)
    groups = [("all", "all points", np.ones(len(norm), bool))]
    for family, lab in labels.items():
        groups += [(family, str(r), lab == r) for r in sorted(np.unique(lab), key=_order)]
    n_tests = len(groups)
    out = []
    for family, region, mask in groups:
        e = norm[mask]
        if e.size == 0:
            continue
        p = (
            float(ttest_1samp(e, floor.mean_m, alternative="greater").pvalue)
            if e.size > 1 and np.ptp(e) > 0
            else 1.0
        )
        out.append(
            RegionStat.of(
                e * 1e3,
                family=family,
                region=region,
                ratio_to_floor=float(e.mean() / floor.mean_m),
                p_value=p,
                significant=p < level / n_tests,
            )
        )
    return out
