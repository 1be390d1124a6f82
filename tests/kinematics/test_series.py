"""A measured series read for fitting: joint limits checked, gross outliers dropped and named."""

import json
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from kinematics.accuracy import accuracy_summary, nominal_poses
from kinematics.calibration import calibrate
from kinematics.dataset import Dataset, read_dataset, write_dataset
from kinematics.errors import DatasetError
from kinematics.identity import description_for
from kinematics.importers.ipa import import_series
from kinematics.outliers import GROSS_THRESHOLD, gross_outliers, robust_distance
from kinematics.series import read_series
from kinematics.transforms import pose_error
from sim_sources.cell import simulate
from sim_sources.scenarios import get_scenario
from stream.cli import main


def moved(ds: Dataset, rows, dz_m: float) -> Dataset:
    """``ds`` with the measured z of ``rows`` moved by ``dz_m``: a lost beam, a swapped
    reflector."""
    table = ds.table.copy()
    table.loc[list(rows), "z"] += dz_m
    return Dataset(table, ds.meta)


def clean_rows_mean_mm(result, ds: Dataset) -> float:
    """Mean position error (mm) of a calibration's model on ``ds``, in the frames it fitted."""
    fitted = Dataset(ds.table, replace(ds.meta, T_W_0=result.T_W_0.tolist(), T_6_S=None))
    return accuracy_summary(fitted, result.description).mean_mm


@pytest.fixture(scope="module")
def series_b(shared_data, tmp_path_factory) -> Path:
    out = tmp_path_factory.mktemp("series_b") / "b.parquet"
    return import_series(shared_data / "ur10-ipa" / "Series_B", out=out).path


@pytest.fixture(scope="module")
def campaign() -> Dataset:
    return simulate(get_scenario("paper"), 300, 0)


@pytest.mark.shared_data
def test_a_lost_beam_in_real_series_b_is_dropped_and_named(series_b, tmp_path):
    clean = read_dataset(series_b)
    desc = description_for(clean, None, series_b)
    bad = write_dataset(moved(clean, [13], 1.0), tmp_path / "bad.parquet")
    notices = []
    _, screened = read_series(bad, notify=notices.append)
    assert len(screened) == 1494 and len(notices) == 1
    assert notices[0].startswith(f"{bad}: dropped 1 of 1495 rows as gross outliers (row 13;")
    assert "999." in notices[0] and "\n" not in notices[0]
    # The row 1 m off decides a least-squares calibration; without it the fit is the clean one.
    whole = clean_rows_mean_mm(calibrate(desc, clean), clean)
    unscreened = clean_rows_mean_mm(calibrate(desc, read_dataset(bad)), clean)
    assert whole < 0.45 and unscreened > 2 * whole
    assert clean_rows_mean_mm(calibrate(desc, screened), clean) == pytest.approx(whole, abs=2e-3)
    # The clean series loses nothing.
    assert len(read_series(series_b, notify=notices.append)[1]) == 1495 and len(notices) == 1


@pytest.mark.shared_data
def test_a_lost_beam_is_found_where_the_metadata_lacks_the_tracker_frame(series_b, tmp_path):
    """Tracker-frame poses without ``T_W_0`` (calibration fits it) are judged in frames fitted
    to them: as measured, the row 1 m off lay 16 robust units out."""
    clean = read_dataset(series_b)
    unknown = Dataset(clean.table, replace(clean.meta, T_W_0=None))
    bad = write_dataset(moved(unknown, [13], 1.0), tmp_path / "bad.parquet")
    notices = []
    assert len(read_series(bad, notify=notices.append)[1]) == 1494
    assert "(row 13;" in notices[0]
    kept = write_dataset(unknown, tmp_path / "clean.parquet")
    assert len(read_series(kept, notify=notices.append)[1]) == 1495 and len(notices) == 1


@pytest.mark.shared_data
def test_calibrate_names_the_dropped_row_and_fits_the_rest(series_b, tmp_path, capsys):
    bad = write_dataset(moved(read_dataset(series_b), [13, 700], -0.2), tmp_path / "bad.parquet")
    assert main(["calibrate", "--data", str(bad), "--json"]) == 0
    out = capsys.readouterr()
    assert json.loads(out.out)["residual"]["max_mm"] < 5.0
    err = [line for line in out.err.splitlines() if line.startswith("robocal:")]
    prefix = f"robocal: {bad}: dropped 2 of 1495 rows as gross outliers (row 13, 700; up to "
    assert len(err) == 1 and err[0].startswith(prefix)


def test_one_row_far_off_is_dropped_and_a_change_of_set_up_is_kept(campaign, tmp_path):
    notices = []
    bad = write_dataset(moved(campaign, [5, 250], 0.5), tmp_path / "bad.parquet")
    _, ds = read_series(bad, notify=notices.append)
    assert len(ds) == 298 and "(row 5, 250;" in notices[0]
    assert not np.isin(ds.table["t"], campaign.table["t"].iloc[[5, 250]]).any()
    # A fifth of the rows 0.5 m off is a tracker moved within the file, not faults: all kept.
    shifted = write_dataset(moved(campaign, range(240, 300), 0.5), tmp_path / "shifted.parquet")
    assert len(read_series(shifted, notify=notices.append)[1]) == 300 and len(notices) == 1


def test_a_clean_campaign_lies_far_inside_the_threshold(campaign):
    errors = pose_error(
        campaign.measured_poses_base(), nominal_poses(campaign, description_for(campaign))
    )
    assert robust_distance(errors, errors).max() < GROSS_THRESHOLD / 5
    assert gross_outliers(errors).size == 0


def test_exact_errors_are_judged_at_the_tracker_noise():
    """Errors alike to a nanometre (an exact simulation) are not outliers of each other."""
    errors = np.random.default_rng(0).normal(scale=1e-9, size=(100, 6))
    assert gross_outliers(errors).size == 0
    errors[3, 2] = 0.05  # 50 mm off
    assert gross_outliers(errors).tolist() == [3]


def test_a_joint_past_its_limit_stops_with_one_line(campaign, tmp_path):
    table = campaign.table.copy()
    table.loc[9, "q2"] = 1e6
    path = write_dataset(Dataset(table, campaign.meta), tmp_path / "bad.parquet")
    with pytest.raises(DatasetError, match=r"row 9, column 'q2': .* deg outside the joint limits"):
        read_series(path)


def test_train_names_the_dropped_row(campaign, tmp_path, capsys):
    bad = write_dataset(moved(campaign, [17], 2.0), tmp_path / "bad.parquet")
    out = tmp_path / "m.safetensors"
    assert main(["train", "--data", str(bad), "--out", str(out), "--max-epochs", "3"]) == 0
    err = capsys.readouterr().err
    assert f"robocal: {bad}: dropped 1 of 300 rows as gross outliers (row 17;" in err
