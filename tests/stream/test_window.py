"""The event-time join: table-tested drops, settle test, watermarks, order invariance."""

import random

import pytest

from kinematics.errors import ConfigError
from stream.window import Batcher, Joiner, WindowConfig
from wire import JointSample, TemperatureSample, TrackerSample

CFG = WindowConfig(n_joints=2, batch_size=2, allowed_lateness_s=0.1)
Q = (0.5, -0.25)


def joints(t0, t1, q=Q, speed=0.0, seq0=0, rate=125.0):
    n = int(round((t1 - t0) * rate)) + 1
    return [
        JointSample(seq=seq0 + i, t=t0 + i / rate, q=(q[0] + speed * i / rate, q[1]))
        for i in range(n)
    ]


def temps(t0, t1, seq0=0):
    return [
        TemperatureSample(seq=seq0 + i, t=float(t), names=("ambient",), values=(20.0 + t,))
        for i, t in enumerate(range(int(t0), int(t1) + 1))
    ]


def tracker(t, seq=0):
    return TrackerSample(seq=seq, t=t, xyz=(1.0, 0.0, 0.5), quat=(0.0, 0.0, 0.0, 1.0))


def run(samples, cfg=CFG):
    j = Joiner(cfg)
    points = [p for s in samples for p in j.push(s)] + j.flush()
    return points, dict(j.counter.dropped)


def test_settled_point_joins_nearest_joint_and_temperature():
    points, dropped = run([*joints(0.0, 2.0), *temps(0, 2), tracker(1.5)])
    assert dropped == {}
    (p,) = points
    assert p.q == Q and p.t == 1.5 and p.temperatures == (21.0,)  # as-of: the 1 s sample


@pytest.mark.parametrize(
    "samples, reason",
    [
        ([*joints(0.0, 2.0, speed=0.05), *temps(0, 2), tracker(1.5)], "not_settled"),
        ([*joints(0.0, 1.0), *joints(1.6, 2.0, seq0=200), *temps(0, 2), tracker(1.3)], "no_joints"),
        ([*joints(0.0, 2.0), tracker(1.5)], "no_temperature"),
        ([*joints(1.45, 2.0), *temps(0, 2), tracker(1.5)], "not_settled"),
    ],
)
def test_incomplete_points_are_dropped_by_reason(samples, reason):
    points, dropped = run(samples)
    assert points == [] and dropped == {reason: 1}


def test_stale_temperature_is_not_used():
    cfg = WindowConfig(n_joints=2, temperature_tolerance_s=0.5)
    points, dropped = run([*joints(0.0, 2.0), *temps(0, 0), tracker(1.5)], cfg)
    assert points == [] and dropped == {"no_temperature": 1}


def test_joints_only_robot():
    cfg = WindowConfig(n_joints=2, require_temperatures=False)
    points, dropped = run([*joints(0.0, 2.0), tracker(1.5)], cfg)
    assert len(points) == 1 and points[0].temperatures == () and dropped == {}


@pytest.mark.parametrize(
    "bad, reason",
    [
        (JointSample(seq=5, t=0.04, q=Q), "duplicate"),
        (JointSample(seq=10_000, t=0.5, q=Q), "time_backwards"),
        (JointSample(seq=10_001, t=0.0, q=(0.0,) * 3), "joint_count"),
        (TemperatureSample(seq=9, t=1.9, names=("other",), values=(20.0,)), "temperature_names"),
    ],
)
def test_bad_samples_are_counted_and_change_nothing(bad, reason):
    clean = sorted([*joints(0.0, 2.0), *temps(0, 2), tracker(1.5)], key=lambda s: s.t)
    points_clean, _ = run(clean)
    points, dropped = run([*clean[:-20], bad, *clean[-20:]])
    assert points == points_clean and dropped == {reason: 1}


def test_late_sample_beyond_watermark_is_dropped():
    samples = [*joints(0.0, 2.0, seq0=1000), *temps(0, 2), JointSample(seq=5, t=1.0, q=Q)]
    assert run(samples)[1] == {"late": 1}


def test_tracker_arriving_after_its_joints_were_evicted_is_late():
    cfg = WindowConfig(n_joints=2, max_buffer_s=1.0, allowed_lateness_s=0.0)
    points, dropped = run([*joints(0.0, 5.0), *temps(0, 5), tracker(1.0)], cfg)
    assert points == [] and dropped == {"late": 1}


def test_out_of_order_within_lateness_gives_the_same_points():
    cfg = WindowConfig(n_joints=2, allowed_lateness_s=0.5)
    samples = []
    for k in range(5):
        t0 = 2.0 * k
        samples += joints(t0, t0 + 1.99, q=(0.1 * k, 0.0), seq0=250 * k)
        samples.append(tracker(t0 + 1.5, seq=k))
    samples += temps(0, 10)
    samples.sort(key=lambda s: s.t)
    expected, dropped = run(samples, cfg)
    assert len(expected) == 5 and dropped == {}
    rng = random.Random(0)
    shuffled = list(samples)
    for i in range(0, len(shuffled) - 8, 8):  # local shuffles: disorder of < 0.1 s
        chunk = shuffled[i : i + 8]
        rng.shuffle(chunk)
        shuffled[i : i + 8] = chunk
    assert run(shuffled, cfg) == (expected, {})


def test_points_wait_for_the_watermark():
    j = Joiner(WindowConfig(n_joints=2, allowed_lateness_s=0.5))
    for s in [*joints(0.0, 1.8), *temps(0, 1), tracker(1.5)]:
        assert j.push(s) == []
    assert j.pending == 1
    out = [p for s in joints(1.808, 2.1, seq0=500) + temps(2, 2, seq0=10) for p in j.push(s)]
    assert [p.t for p in out] == [1.5]


def test_batcher_groups_and_flushes():
    b = Batcher(2)
    points, _ = run(
        [*joints(0.0, 5.99), *temps(0, 6), tracker(1.5, 0), tracker(3.5, 1), tracker(5.5, 2)]
    )
    batches = b.add(points) + b.flush()
    assert [len(x.points) for x in batches] == [2, 1] and [x.seq for x in batches] == [0, 1]


@pytest.mark.parametrize(
    "field, value",
    [
        ("batch_size", 0),
        ("settle_window_s", 0.0),
        ("allowed_lateness_s", -1.0),
        ("settle_velocity_rad_s", 0.0),
    ],
)
def test_config_rejects_bad_values(field, value):
    with pytest.raises(ConfigError, match=field):
        WindowConfig(**{field: value})
