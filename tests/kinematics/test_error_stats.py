"""The one error-statistics record: its conventions and the JSON keys of the records on it."""

import numpy as np
import pytest

from kinematics.accuracy import AccuracySummary
from kinematics.calibration import ResidualStats, residual_stats
from kinematics.error_stats import ErrorStats
from kinematics.frames import FitSummary
from kinematics.gap.regions import RegionStat
from kinematics.transforms import transform_from_xyz_rpy
from learner.metrics import AccuracyReport


def test_statistics_and_the_sample_std_convention():
    mm = np.array([0.5, 1.0, 1.5, 4.0])
    s = ErrorStats.of(mm, np.array([1.0, 2.0, 3.0, 6.0]))
    assert (s.n, s.mean_mm, s.max_mm) == (4, 1.75, 4.0)
    assert s.std_mm == pytest.approx(np.sqrt(((mm - 1.75) ** 2).sum() / 3))  # n - 1
    assert s.rms_mm == pytest.approx(np.sqrt((mm**2).mean()))
    assert s.p95_mm == pytest.approx(np.percentile(mm, 95))
    assert (s.mean_arcmin, s.max_arcmin) == (3.0, 6.0)
    one = ErrorStats.of(np.array([2.0]))
    assert one.std_mm == 0.0 and np.isnan([one.mean_arcmin, one.rms_arcmin]).all()


def test_residual_stats_of_poses():
    T = np.repeat(np.eye(4)[None], 3, axis=0)
    P = T.copy()
    P[:, 0, 3] = [1e-3, 2e-3, 3e-3]
    P[2] = P[2] @ transform_from_xyz_rpy([0, 0, 0], [0, 0, np.deg2rad(1.0)])
    s = residual_stats(T, P)
    assert isinstance(s, ResidualStats) and (s.mean_mm, s.std_mm) == pytest.approx((2.0, 1.0))
    assert s.max_arcmin == pytest.approx(60.0) and s.mean_arcmin == pytest.approx(20.0)


@pytest.mark.parametrize(
    "record, keys",
    [
        (ErrorStats, "n mean_mm std_mm rms_mm p95_mm max_mm mean_arcmin rms_arcmin max_arcmin"),
        (AccuracySummary, "n mean_mm std_mm max_mm p95_mm mean_arcmin max_arcmin"),
        (ResidualStats, "n mean_mm rms_mm std_mm max_mm mean_arcmin max_arcmin"),
        (FitSummary, "n mean_mm rms_mm max_mm mean_arcmin rms_arcmin max_arcmin"),
        (RegionStat, "family region n mean_mm rms_mm max_mm ratio_to_floor p_value significant"),
        (
            AccuracyReport,
            "n mean_mm std_mm max_mm p95_mm mean_arcmin uncalibrated_mean_mm improvement_pct "
            "coverage_68 coverage_90 coverage_95 interval_width_90_mm nll",
        ),
    ],
)
def test_every_record_is_one_and_keeps_its_json_keys(record, keys):
    """The keys the CLI's JSON, snapshots' metrics and dataset metadata have always had."""
    assert issubclass(record, ErrorStats) and tuple(keys.split()) == record.KEYS
