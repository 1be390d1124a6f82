"""No poisoning: a tracker burst is quarantined and never learned, clean points and a genuine
drift pass, a lasting shift is released, and the publish gate keeps the last good model."""

from dataclasses import replace

import numpy as np
import pytest
import torch

from kinematics.errors import ConfigError
from learner.config import ContinualConfig, ModelConfig, QuarantineConfig, TrainConfig
from learner.continual import ContinualLearner
from learner.continual_state import state_from_bytes, state_to_bytes
from learner.model import ErrorModel
from learner.quarantine import QuarantineState, screen, withhold
from learner.workflow import prepare
from tests.learner.conftest import make_dataset

CFG = QuarantineConfig()


def _clean(n: int, seed: int = 0, sigma: float = 5e-5) -> tuple[np.ndarray, np.ndarray]:
    """Labels (the robot's error, about 1 mm) and model residuals (heavy-tailed, ``sigma``)."""
    rng = np.random.default_rng(seed)
    return rng.normal(0.0, 1e-3, (n, 6)), rng.standard_t(4, size=(n, 6)) * sigma


def _stream(y, r, batch: int, cfg: QuarantineConfig = CFG, sigma: float = 5e-5):
    """Screen batch by batch; per point whether it was kept out, and the last state."""
    state, out = QuarantineState.empty(), []
    for i in range(0, len(r), batch):
        s = slice(i, i + batch)
        ok, state = screen(y[s], r[s], r[s] / sigma, state, cfg)
        out.append(~ok)
    return np.concatenate(out), state


def _bumped(y, r, start: int, mm: float, n: int = 30):
    """The tracker moved by ``mm`` for ``n`` points: labels and residuals both move."""
    y, r = y.copy(), r.copy()
    for a in (y, r):
        a[start : start + n, :3] += 1e-3 * mm * np.array([0.6, -0.48, 0.64])
    return y, r


@pytest.mark.parametrize("mm", [20.0, 50.0])
@pytest.mark.parametrize("batch", [20, 100])
def test_a_tracker_burst_is_quarantined_and_clean_points_are_not(mm, batch):
    y, r = _clean(2000)
    out, state = _stream(y, r, batch)
    assert out.sum() == 0 and state.quarantined == 0
    out, state = _stream(*_bumped(y, r, 1010, mm), batch)
    assert np.flatnonzero(out).tolist() == list(range(1010, 1040))
    assert state.quarantined == 30 and state.released == 0
    assert len(state.labels) == len(state.residuals) == CFG.history  # accepted points only


def test_a_drift_a_wide_interval_and_a_bad_extrapolation_are_not_quarantined():
    y, r = _clean(3000)
    drift = np.linspace(0.0, 2e-3, 3000)  # 2 mm over the stream, never learned by the model
    y[:, 0] += drift
    r[:, 0] += drift
    out, _ = _stream(y, r, 50)
    assert out.sum() == 0
    y, r = _bumped(*_clean(600), 300, 20.0)
    out, _ = _stream(y, r, 100, sigma=1e-2)  # a model 10 mm unsure says it does not know
    assert out.sum() == 0
    y, r = _clean(600)
    r[300:330, :3] += 0.02  # the model is 20 mm off where the robot's error is ordinary
    out, _ = _stream(y, r, 100)
    assert out.sum() == 0


def test_a_lasting_shift_is_released_after_release_after_points():
    y, r = _clean(1200)
    y[600:, 2] += 0.03  # the tracker moved for good
    r[600:, 2] += 0.03
    cfg = replace(CFG, release_after=60)
    out, state = _stream(y, r, 25, cfg)
    assert np.flatnonzero(out).tolist() == list(range(600, 659))
    assert state.released == 1 and state.quarantined == 59


def test_warm_up_catches_only_gross_outliers_and_off_means_off():
    labels = np.random.default_rng(1).normal(0.0, 1e-3, (50, 6))  # uncalibrated errors, mm
    labels[7, :3] += 0.2  # 200 mm in the first points: caught even without a model
    labels[8, :3] += 0.005  # 5 mm is a robot's own error: not judged before a model
    ok, state = screen(labels, None, None, QuarantineState.empty(), CFG)
    assert np.flatnonzero(~ok).tolist() == [7] and len(state.residuals) == 0
    ok, _ = screen(labels, None, None, QuarantineState.empty(), replace(CFG, enabled=False))
    assert ok.all()


def test_gate_rule_and_config_validation():
    assert withhold(1.0, 1.11, 20, CFG) and not withhold(1.0, 1.09, 20, CFG)
    assert not withhold(1.0, 5.0, 19, CFG)  # too few held-out points to judge
    assert not withhold(1.0, 5.0, 50, replace(CFG, publish_tolerance=float("inf")))
    assert ContinualConfig(quarantine={"threshold": 10}).quarantine.threshold == 10
    for bad, match in (
        ({"threshold": 0}, "threshold"),
        ({"history": 0}, "history"),
        ({"label_threshold": -1}, "label_threshold"),
        ({"publish_tolerance": -1}, "publish_tolerance"),
        ({"nope": 1}, "nope"),
    ):
        with pytest.raises(ConfigError, match=match):
            ContinualConfig(quarantine=bad)


@pytest.fixture(scope="module")
def points():
    return prepare(make_dataset(420, seed=5), test_fraction=0.0)


def _learner(p, quarantine: QuarantineConfig = CFG) -> ContinualLearner:
    model = ErrorModel.create(
        p.spec, ModelConfig(hidden_layers=1, neurons=16), TrainConfig(max_epochs=60), 0
    )
    cfg = ContinualConfig(
        memory=400, batch=40, init=100, epochs_per_update=10, holdout=0.25, quarantine=quarantine
    )
    return ContinualLearner(model, cfg)


def test_the_learner_keeps_a_burst_out_of_memory_and_held_out_set(points):
    p = points
    Y = p.Y.copy()
    # The tracker bumped by 40 mm; this robot's own error spreads 2.6 mm (MAD per component),
    # so 20 mm would lie below label_threshold (10) of them: the robot could have done it.
    Y[230:260, :3] += 0.04 * np.array([0.0, 0.6, 0.8])
    learner = _learner(p)
    steps = list(learner.learn_stream(p.X, Y))
    assert sum(s.quarantined for s in steps) == learner.quarantine.quarantined == 30
    assert learner.n_seen == len(p.X)  # every point given is counted, kept out or not
    state = learner.state_dict()
    for x in (state["memory_x"], state["holdout_x"]):
        rows = {r.tobytes() for r in x}
        assert not rows & {r.tobytes() for r in p.X[230:260]}
    assert len(learner.memory) + len(state["holdout_x"]) == len(p.X) - 30
    restored = _learner(p)
    restored.load_state(state_from_bytes(state_to_bytes(state)))
    assert restored.quarantine.quarantined == 30
    np.testing.assert_array_equal(restored.quarantine.labels, learner.quarantine.labels)
    np.testing.assert_array_equal(restored.quarantine.residuals, learner.quarantine.residuals)
    clean = _learner(p)
    list(clean.learn_stream(p.X, p.Y))
    assert clean.quarantine.quarantined == 0


def test_the_gate_keeps_the_last_good_model(points):
    p = points
    learner = _learner(p, replace(CFG, gate_min_points=10))
    list(learner.learn_stream(p.X[:340], p.Y[:340]))  # 60 held-out points
    version, before = learner.version, learner.model.predict(p.X).gamma
    with torch.no_grad():  # what poison that slipped through does to the trained weights
        for w in learner.trained.net.parameters():
            w.add_(3.0 * torch.randn_like(w, generator=torch.Generator().manual_seed(0)))
    m = learner.update(p.X[340:380], p.Y[340:380])
    assert m.withheld and learner.n_withheld == 1 and learner.version == version
    np.testing.assert_array_equal(learner.model.predict(p.X).gamma, before)
    off = _learner(p, replace(CFG, publish_tolerance=float("inf")))
    list(off.learn_stream(p.X[:340], p.Y[:340]))
    with torch.no_grad():
        for w in off.trained.net.parameters():
            w.add_(3.0 * torch.randn_like(w, generator=torch.Generator().manual_seed(0)))
    published = off.update(p.X[340:380], p.Y[340:380])  # what the gate kept from the line
    assert not published.withheld and off.version == version + 1
    assert published.holdout_mm > 1.1 * m.holdout_mm
