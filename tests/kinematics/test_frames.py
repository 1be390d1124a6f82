"""Robot-world / hand-eye calibration on synthetic data from a real pinocchio UR10 model."""

import numpy as np
import pandas as pd
import pytest
from scipy.spatial.transform import Rotation

from kinematics.dataset import Dataset, DatasetMeta
from kinematics.description import load_description
from kinematics.errors import ConfigError, DatasetError, IdentifiabilityError
from kinematics.frames import (
    FrameFit,
    FrameFitConfig,
    closed_form_axzb,
    fit_frames,
    fit_frames_positions,
    identify_frames,
    reframed,
    tracker_to_base,
)
from kinematics.model import RobotModel
from kinematics.transforms import (
    invert,
    transform,
    transform_from_xyz_rpy,
    xyz_quat_from_transform,
)

T_W_0 = transform_from_xyz_rpy([2.4, -1.3, -1.2], [0.01, -0.02, -0.52])
T_6_S = transform_from_xyz_rpy([0.0004, -0.0006, 0.093], [0.002, -0.001, -1.5716])


@pytest.fixture(scope="module")
def flange() -> np.ndarray:
    q = np.random.default_rng(1).uniform(-np.pi, np.pi, (200, 6))
    return RobotModel(load_description("ur10")).fk(q, frame="flange")


def measured(flange: np.ndarray, pos_noise_m: float = 0.0, rot_noise_rad: float = 0.0, seed=0):
    rng = np.random.default_rng(seed)
    T = T_W_0[None] @ flange @ T_6_S[None]
    noise = transform(
        Rotation.from_rotvec(rng.normal(0, rot_noise_rad, (len(T), 3))).as_matrix(),
        rng.normal(0, pos_noise_m, (len(T), 3)),
    )
    return T @ noise


def frame_gap(T_a, T_b) -> tuple[float, float]:
    """Position (m) and angle (rad) between two frames."""
    return (
        float(np.linalg.norm(T_a[:3, 3] - T_b[:3, 3])),
        float(Rotation.from_matrix(T_a[:3, :3] @ T_b[:3, :3].T).magnitude()),
    )


def test_closed_form_is_exact_without_noise(flange):
    W0, S6 = closed_form_axzb(measured(flange), flange)
    assert max(frame_gap(W0, T_W_0)) < 1e-9
    assert max(frame_gap(S6, T_6_S)) < 1e-9


def test_fit_recovers_frames_to_micrometres_without_noise(flange):
    fit = fit_frames(measured(flange), flange)
    for found, true in ((fit.T_W_0, T_W_0), (fit.T_6_S, T_6_S)):
        dp, dr = frame_gap(found, true)
        assert dp < 1e-6 and dr < 1e-6
    assert fit.summary().max_mm < 1e-3 and fit.success


def test_residuals_match_the_noise(flange):
    sigma_m, sigma_rad = 50e-6, 50e-6
    fit = fit_frames(measured(flange, sigma_m, sigma_rad, seed=3), flange)
    s = fit.summary()
    # 3-D Gaussian noise: RMS norm = sqrt(3) sigma, less the 12 fitted parameters' share.
    assert s.rms_mm == pytest.approx(np.sqrt(3) * sigma_m * 1e3, rel=0.15)
    assert s.rms_arcmin == pytest.approx(np.sqrt(3) * sigma_rad * 60 * 180 / np.pi, rel=0.15)
    dp, dr = frame_gap(fit.T_6_S, T_6_S)
    assert dp < 3 * sigma_m and dr < 3 * sigma_rad


@pytest.mark.parametrize(
    "bad_W0, bad_S6",
    [
        (transform_from_xyz_rpy([1.0, 1.0, 1.0], [1.0, -0.5, 2.0]), np.eye(4)),
        (None, invert(T_6_S)),  # the wrong direction, as a transform file may give it
        (T_W_0 @ transform_from_xyz_rpy([0.3, 0, 0], [0, 0, np.pi]), T_6_S),
    ],
)
def test_bad_start_still_converges(flange, bad_W0, bad_S6):
    fit = fit_frames(measured(flange), flange, T_W_0_init=bad_W0, T_6_S_init=bad_S6)
    assert max(frame_gap(fit.T_W_0, T_W_0)) < 1e-6
    assert max(frame_gap(fit.T_6_S, T_6_S)) < 1e-6


def test_refinement_improves_on_the_closed_form_under_noise(flange):
    T = measured(flange, 200e-6, 200e-6, seed=7)
    W0, S6 = closed_form_axzb(T, flange)
    closed_rms = np.sqrt(np.mean(np.sum((W0 @ flange @ S6 - T)[:, :3, 3] ** 2, axis=1)))
    assert fit_frames(T, flange).summary().rms_mm < 1e3 * closed_rms


def test_robust_loss_resists_outliers(flange):
    T = measured(flange, 20e-6, 20e-6)
    T[::20, :3, 3] += 0.01  # 10 outliers of 17 mm
    plain = fit_frames(T, flange)
    robust = fit_frames(T, flange, config=FrameFitConfig(loss="soft_l1", f_scale_m=1e-4))
    assert frame_gap(robust.T_W_0, T_W_0)[0] < 0.2 * frame_gap(plain.T_W_0, T_W_0)[0]


def test_position_only_fit(flange):
    rng = np.random.default_rng(5)
    p = measured(flange)[:, :3, 3] + rng.normal(0, 20e-6, (len(flange), 3))
    fit = fit_frames_positions(p, flange)
    assert fit.residual_arcmin is None
    assert np.isnan(fit.summary().mean_arcmin)
    assert frame_gap(fit.T_W_0, T_W_0)[0] < 1e-4
    assert np.linalg.norm(fit.T_6_S[:3, 3] - T_6_S[:3, 3]) < 1e-4
    assert fit.summary().rms_mm == pytest.approx(np.sqrt(3) * 0.02, rel=0.15)


def test_tracker_to_base_inverts_the_base_frame(flange):
    T_0_S = tracker_to_base(measured(flange), T_W_0)
    np.testing.assert_allclose(T_0_S, flange @ T_6_S[None], atol=1e-12)


def test_degenerate_rotations_are_refused(flange):
    same = np.broadcast_to(flange[0], (10, 4, 4)).copy()
    same[:, :3, 3] += np.random.default_rng(0).normal(0, 0.1, (10, 3))
    with pytest.raises(IdentifiabilityError, match="rotations do not determine"):
        closed_form_axzb(T_W_0[None] @ same @ T_6_S[None], same)


@pytest.mark.parametrize(
    "args, match",
    [
        ((np.zeros((2, 4, 4)), np.zeros((2, 4, 4))), "need >= 3"),
        ((np.zeros((5, 3, 3)), np.zeros((5, 4, 4))), r"T_W_S must have shape \(N, 4, 4\)"),
        ((np.full((5, 4, 4), np.nan), np.zeros((5, 4, 4))), "T_W_S contains non-finite"),
    ],
)
def test_bad_input_is_one_line(args, match):
    with pytest.raises(IdentifiabilityError, match=match):
        fit_frames(*args)


def test_config_validation():
    with pytest.raises(ConfigError, match="orientation_weight_m must be > 0, got -1"):
        FrameFitConfig(orientation_weight_m=-1)
    with pytest.raises(ConfigError, match="loss"):
        FrameFitConfig(loss="l2")


def test_identify_frames_from_joint_angles():
    model = RobotModel(load_description("ur10"))
    q = np.random.default_rng(2).uniform(-2.0, 2.0, (30, 6))
    fit = identify_frames(model, q, T_W_0[None] @ model.fk(q, frame="flange") @ T_6_S[None])
    assert max(frame_gap(fit.T_W_0, T_W_0)) < 1e-9 and max(frame_gap(fit.T_6_S, T_6_S)) < 1e-9


def tracker_dataset(T_W_S: np.ndarray, q: np.ndarray, frames_fit: FrameFit) -> Dataset:
    """A tracker-frame dataset of poses ``T_W_S`` at angles ``q``, its frames ``frames_fit``'s."""
    xyz, quat = xyz_quat_from_transform(T_W_S)
    columns = {"t": np.arange(len(q), dtype=float)}
    columns |= {f"q{i + 1}": q[:, i] for i in range(6)}
    columns |= dict(zip(("x", "y", "z", "qx", "qy", "qz", "qw"), [*xyz.T, *quat.T], strict=True))
    meta = DatasetMeta(
        robot="ur10",
        frame="tracker",
        T_W_0=frames_fit.T_W_0.tolist(),
        T_6_S=frames_fit.T_6_S.tolist(),
    )
    return Dataset(pd.DataFrame(columns), meta)


def test_a_day_reframed_on_its_first_points_has_their_frames_not_the_whole_days():
    """A tracker bumped by 2 mm / 2 mrad halfway through a day: frames fitted on every row
    (as an importer does) are neither; the day's first points alone give the first frames."""
    model = RobotModel(load_description("ur10"))
    q = np.random.default_rng(2).uniform(-np.pi, np.pi, (120, 6))
    flange = model.fk(q, frame="flange")
    bumped = transform_from_xyz_rpy([0.002, 0.0, -0.001], [0.002, 0.0, 0.0]) @ T_W_0
    T_W_S = np.concatenate([T_W_0[None] @ flange[:60], bumped[None] @ flange[60:]]) @ T_6_S[None]
    ds = tracker_dataset(T_W_S, q, fit_frames(T_W_S, flange, T_6_S_init=T_6_S))
    assert frame_gap(np.asarray(ds.meta.T_W_0), T_W_0)[0] > 3e-4
    first = reframed(ds, model.description, np.arange(30))
    assert max(frame_gap(np.asarray(first.meta.T_W_0), T_W_0)) < 1e-8
    assert max(frame_gap(np.asarray(first.meta.T_6_S), T_6_S)) < 1e-8
    later = reframed(ds, model.description, np.arange(70, 120))
    assert max(frame_gap(np.asarray(later.meta.T_W_0), bumped)) < 1e-8
    assert first.table is ds.table and ds.meta.T_W_0 != first.meta.T_W_0


def test_reframing_a_base_frame_dataset_is_refused_in_one_line():
    ds = Dataset(pd.DataFrame({"t": [0.0]}), DatasetMeta(robot="ur10", frame="base"))
    with pytest.raises(DatasetError, match="needs tracker-frame poses, the dataset's are base"):
        reframed(ds, load_description("ur10"), np.arange(1))
