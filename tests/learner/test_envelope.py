"""What a model was trained on: the arc per joint on the circle and the range per thermometer,
how fit and the continual learner widen it, and that snapshots carry it."""

import json

import numpy as np
import pytest
import torch
from safetensors.torch import load as st_load
from safetensors.torch import save as st_save

from kinematics.errors import SnapshotError
from learner.config import ContinualConfig, ModelConfig, TrainConfig
from learner.continual import ContinualLearner
from learner.envelope import MARGIN_K, Envelope, outside, why_outside, widen
from learner.features import FeatureSpec
from learner.metrics import past_envelope
from learner.model import ErrorModel
from learner.snapshot import read_metadata, snapshot_from_bytes, snapshot_to_bytes

SPEC = FeatureSpec(
    names=("q1", "q2", "temp_a"), low=np.array([-4.0, -4.0, 0.0]), high=np.array([4.0, 4.0, 50.0])
)


def deg(*angles):
    return np.deg2rad(np.array(angles, dtype=float))


def test_the_arc_spans_the_training_angles_the_short_way_round():
    seen = widen(None, deg(170, -175, -160, 178)[:, None])  # across ±180°
    assert not outside(seen, deg(175, -170, 180, -180)[:, None]).any()
    assert outside(seen, deg(0, 90, -90, 150)[:, None]).all()
    # 360° apart is the same angle; a joint seen all the way round is never outside
    assert not outside(seen, deg(170 - 360, -160 + 720)[:, None]).any()
    full = widen(None, deg(*range(-180, 180, 4))[:, None])
    assert not outside(full, deg(*range(-720, 720, 7))[:, None]).any()


def test_the_margin_and_the_largest_gap():
    seen = widen(None, deg(0, 90, 180, 200)[:, None])  # the largest gap: 200..360
    assert not outside(seen, deg(45, 135, 190)[:, None]).any()  # gaps inside
    assert not outside(seen, deg(207)[:, None]).any()  # 5° past the last bin
    assert outside(seen, deg(215, 300, -10)[:, None]).all()
    assert outside(seen, deg(-10)[:, None], margin_deg=0.0).all()
    assert not outside(seen, deg(-10)[:, None], margin_deg=10.0).any()
    assert why_outside(seen, deg(300)) == (
        "q1 = 300.0 deg is more than 5 deg outside the angles trained on (0..205 deg)"
    )
    assert why_outside(seen, deg(100)) == ""


def test_each_joint_is_checked_and_widening_is_a_union():
    a = widen(None, deg([0, 0], [30, 10]))
    b = widen(a, deg([100, 5]))
    q = deg([90, 5], [15, 5], [15, 60])
    assert outside(a, q).tolist() == [True, False, True]
    assert outside(b, q).tolist() == [False, False, True]
    assert why_outside(b, deg(15, 60)).startswith("q2 = 60.0 deg")


def _model(seed=0):
    return ErrorModel.create(
        SPEC,
        ModelConfig(hidden_layers=1, neurons=8, encoding="minmax"),
        TrainConfig(max_epochs=5, batch_size=32),
        seed=seed,
    )


def _points(rng, n, q1):
    X = np.column_stack([rng.uniform(*q1, n), rng.uniform(-1, 1, n), rng.uniform(15, 30, n)])
    return X, 1e-4 * np.sin(X[:, :1] + np.arange(6))


def test_a_thermometer_past_its_trained_readings_by_more_than_the_margin_is_outside():
    seen = widen(None, deg(0, 10)[:, None], {"temp_a": [22.0, 23.5]})
    seen = widen(seen, deg(5)[:, None], {"temp_a": [21.0], "temp_b": [30.0]})  # a union
    assert seen.temperatures == {"temp_a": (21.0, 23.5), "temp_b": (30.0, 30.0)}
    lo, hi = 21.0 - MARGIN_K, 23.5 + MARGIN_K
    temps = {"temp_a": [lo + 1e-9, hi, hi + 0.1, lo - 0.1], "temp_b": 30.0}
    assert outside(seen, deg(5, 5, 5, 5)[:, None], temps).tolist() == [False, False, True, True]
    assert outside(seen, deg(5)[:, None], {"temp_a": 24.6}, margin_k=2.0).tolist() == [False]
    assert not outside(seen, deg(5)[:, None], {"temp_c": 99.0}).any()  # never trained: unknown
    assert why_outside(seen, deg(5), {"temp_c": float("nan")}) == ""  # the same for people
    assert outside(seen, deg(5)[:, None], {"temp_a": float("nan")}).all()  # as why_outside says
    assert why_outside(seen, deg(5), {"temp_a": float("nan")}).startswith("temp_a = nan degC")
    assert why_outside(seen, deg(5), {"temp_a": 22.0, "temp_b": 28.5}) == (
        f"temp_b = 28.5 degC is more than {MARGIN_K:g} K outside the temperatures trained on "
        "(30.0..30.0 degC)"
    )
    assert why_outside(seen, deg(90), {"temp_b": 0.0}).startswith("q1 = 90.0 deg")  # joints first


def test_fit_records_the_envelope_and_snapshots_carry_it():
    rng = np.random.default_rng(0)
    X, Y = _points(rng, 80, (-1.0, 0.0))
    m = _model()
    assert m.envelope is None and not past_envelope(m, X).any()
    m.fit(X, Y)
    lo, hi = m.envelope.temperatures["temp_a"]
    assert (lo, hi) == (X[:, 2].min(), X[:, 2].max())
    far = np.array([[0.8, 0.0, 20.0], [-0.5, 0.0, hi + 2 * MARGIN_K], [-0.5, 0.0, hi]])
    assert past_envelope(m, far).tolist() == [True, True, False]
    assert not past_envelope(m, X).any()
    back = snapshot_from_bytes(snapshot_to_bytes(m))
    np.testing.assert_array_equal(back.envelope.joints, m.envelope.joints)
    assert back.envelope.temperatures == m.envelope.temperatures
    m.envelope = Envelope(m.envelope.joints, None)  # as a snapshot written before temperatures
    old = snapshot_from_bytes(snapshot_to_bytes(m))
    assert old.envelope.temperatures is None
    assert past_envelope(old, far).tolist() == [True, False, False]
    old.fit(X[:20], Y[:20])  # going on learning: what it learned before is still unknown
    assert old.envelope.temperatures is None and not past_envelope(old, far)[1:].any()
    m.envelope = None  # as a snapshot written before the envelope existed
    assert snapshot_from_bytes(snapshot_to_bytes(m)).envelope is None
    m.envelope = Envelope(np.ones((3, 72), dtype=bool))  # forged: 3 joints for a 2-joint model
    with pytest.raises(SnapshotError, match=r"joint_envelope has shape \(3, 72\), expected"):
        snapshot_from_bytes(snapshot_to_bytes(m))
    data = snapshot_to_bytes(_model())
    tensors = st_load(data)
    tensors["joint_envelope"] = torch.zeros((2, 72), dtype=torch.uint8)
    tensors["temperature_envelope"] = torch.zeros((2, 2), dtype=torch.float64)  # 1 thermometer
    forged = st_save(tensors, metadata={"robocal": json.dumps(read_metadata(data))})
    with pytest.raises(SnapshotError, match=r"temperature_envelope has shape \(2, 2\), expected"):
        snapshot_from_bytes(forged)


def test_the_published_model_of_a_stream_widens_as_the_stream_goes_on():
    rng = np.random.default_rng(1)
    X1, Y1 = _points(rng, 100, (-1.0, 0.0))
    X2, Y2 = _points(rng, 100, (0.0, 1.0))
    cfg = ContinualConfig(memory=50, batch=25, init=25, epochs_per_update=5, init_epochs=5)
    learner = ContinualLearner(_model(), cfg)
    for _ in learner.learn_stream(X1, Y1):
        pass
    probe = np.array([[0.8, 0.0, 20.0]])
    assert past_envelope(learner.model, probe)[0]
    for _ in learner.learn_stream(X2, Y2):
        pass
    assert not past_envelope(learner.model, probe)[0]
    # the memory holds 50 points, the envelope every angle learned
    assert not past_envelope(learner.model, np.concatenate([X1, X2])).any()
    again = ContinualLearner(_model(), cfg)  # a restarted daemon, from the learner's state
    again.load_state(learner.state_dict())
    for a, b in ((again.model, learner.model), (again.trained, learner.trained)):
        np.testing.assert_array_equal(a.envelope.joints, b.envelope.joints)
        assert a.envelope.temperatures == b.envelope.temperatures


@pytest.mark.parametrize("margin", [-1.0, float("nan")])
def test_a_bad_margin_is_a_config_error(margin):
    from kinematics.errors import ConfigError
    from stream.compensation import CompensationConfig

    with pytest.raises(ConfigError, match="envelope_margin_deg"):
        CompensationConfig(envelope_margin_deg=margin)
    with pytest.raises(ConfigError, match="envelope_margin_k"):
        CompensationConfig(envelope_margin_k=margin)
