"""The learner stage core: hold-out, updates, duplicates, checkpoint -> restart continues,
quarantined points neither tested nor learned."""

import io
import os
import time
from dataclasses import replace

import numpy as np
import pytest
import torch

from kinematics.description import load_description
from kinematics.errors import ConfigError
from learner.config import ContinualConfig, ModelConfig, TrainConfig
from learner.holdout import holdout_mask
from learner.snapshot import snapshot_from_bytes
from sim_sources.cell import simulate
from sim_sources.scenarios import get_scenario
from stream.bus import BusConfig, free_port, open_session
from stream.learner_core import LearnerCore, LearnerStageConfig
from stream.log import JsonLogger
from stream.points import dataset_to_points
from stream.stages.learner_stage import LearnerStage, read_checkpoint, write_checkpoint
from tests.stream.conftest import wait_subscribed
from wire import Batch, Diagnostics, Metrics, RejectedMessageError, decode, encode, key

CFG = LearnerStageConfig(
    model=ModelConfig(hidden_layers=1, neurons=16),
    train=TrainConfig(batch_size=16),
    continual=ContinualConfig(memory=40, batch=20, init=20, epochs_per_update=5, init_epochs=30),
    holdout_every=5,
)


@pytest.fixture(scope="module")
def batches():
    torch.set_num_threads(1)
    ds = simulate(get_scenario("paper"), 100, 1)
    points = dataset_to_points(ds)
    return ds, [Batch(seq=i, points=tuple(points[20 * i : 20 * i + 20])) for i in range(5)]


#: New days after pauses over 4 h (off by default).
NEW_DAYS = replace(CFG, new_day_after_h=4.0)


def core(ds, cfg=CFG):
    return LearnerCore(load_description(ds.meta.robot), cfg, np.asarray(ds.meta.T_W_0))


def test_updates_hold_out_every_fifth_point_and_report_metrics(batches):
    ds, bs = batches
    c = core(ds)
    updates = [c.add_batch(b) for b in bs]
    assert updates[0] is None  # 16 training points < init
    versions = [u.metrics.model_version for u in updates if u is not None]
    assert versions == [1, 2, 3, 4]
    assert len(c.test_y) == 20 and c.learner.n_seen == 80
    m = updates[-1].metrics
    assert np.isfinite([m.test_mean_mm, m.epistemic_mm, m.aleatoric_mm]).all()
    assert sum(m.memory_age) == m.memory_size == 40
    with pytest.raises(RejectedMessageError, match="duplicate"):
        c.add_batch(bs[2])


def test_checkpoint_restart_continues_exactly(batches, tmp_path):
    ds, bs = batches
    straight = core(ds)
    for b in bs:
        straight.add_batch(b)
    first = core(ds)
    for b in bs[:3]:
        first.add_batch(b)
    write_checkpoint(first, tmp_path / "ck.safetensors")
    resumed = core(ds)
    read_checkpoint(resumed, tmp_path / "ck.safetensors")
    for b in bs[3:]:
        resumed.add_batch(b)
    x = straight.test_x
    np.testing.assert_array_equal(
        resumed.learner.model.predict(x).gamma, straight.learner.model.predict(x).gamma
    )
    assert resumed.metrics(0.0, 0.0, 0.0) == straight.metrics(0.0, 0.0, 0.0)


def test_a_checkpoint_of_another_network_shape_restores_as_it_was_trained(batches, tmp_path):
    """A daemon upgraded to a new default shape (or given another ``[learner.model]``) goes on
    from its checkpoint with the network the checkpoint holds, not the configured one."""
    ds, bs = batches
    first = core(ds)
    for b in bs[:3]:
        first.add_batch(b)
    write_checkpoint(first, tmp_path / "ck.safetensors")
    deeper = replace(CFG, model=replace(CFG.model, hidden_layers=2))
    resumed = LearnerCore(load_description(ds.meta.robot), deeper, np.asarray(ds.meta.T_W_0))
    read_checkpoint(resumed, tmp_path / "ck.safetensors")
    assert resumed.learner.model.model_cfg.hidden_layers == 1
    x = first.test_x
    np.testing.assert_array_equal(
        resumed.learner.model.predict(x).gamma, first.learner.model.predict(x).gamma
    )
    assert resumed.add_batch(bs[3]).metrics.model_version == first.learner.version + 1


def test_checkpoint_files_are_written_by_the_one_writer_and_read_back_named(batches, tmp_path):
    """Nothing before a model; the file gets the umask's mode (the shared atomic writer, not
    mkstemp's 0600) and no temporary file; a file that is not a checkpoint is named."""
    from kinematics.dataset import current_umask
    from kinematics.errors import SnapshotError
    from learner.snapshot import save_snapshot

    ds, bs = batches
    c = core(ds)
    assert write_checkpoint(c, tmp_path / "none.safetensors") is None
    assert not (tmp_path / "none.safetensors").exists()
    for b in bs[:2]:
        c.add_batch(b)
    path = write_checkpoint(c, tmp_path / "sub" / "ck.safetensors")
    assert path.stat().st_mode & 0o777 == 0o666 & ~current_umask()
    assert [p.name for p in path.parent.iterdir()] == ["ck.safetensors"]
    garbage = tmp_path / "garbage.safetensors"
    garbage.write_bytes(b"not a checkpoint")
    with pytest.raises(SnapshotError, match=r"garbage\.safetensors: unreadable checkpoint"):
        read_checkpoint(core(ds), garbage)
    model = save_snapshot(c.learner.model, tmp_path / "model.safetensors")
    with pytest.raises(SnapshotError, match=r"model\.safetensors: schema .* is not a checkpoint"):
        read_checkpoint(core(ds), model)
    with pytest.raises(SnapshotError, match=r"missing\.safetensors: unreadable checkpoint"):
        read_checkpoint(core(ds), tmp_path / "missing.safetensors")


def test_a_bad_batch_is_refused_without_touching_the_state(batches):
    ds, bs = batches
    c = core(ds)
    c.add_batch(bs[0])
    c.add_batch(bs[1])
    points = list(bs[2].points)
    points[3] = replace(points[3], frame="base")  # frames differ inside one batch
    with pytest.raises(RejectedMessageError, match="features"):
        c.add_batch(Batch(seq=2, points=tuple(points)))
    assert (c.last_seq, c.n_points, c.learner.version) == (1, 40, 1)
    assert c.add_batch(bs[2]).metrics.model_version == 2


def test_a_carried_model_goes_on_and_a_foreign_one_is_refused(batches, tmp_path):
    from learner.continual import ContinualLearner
    from learner.continual_state import state_path, state_to_bytes
    from learner.snapshot import atomic_write_bytes, save_snapshot

    ds, bs = batches
    day1 = core(ds)
    for b in bs[:3]:
        day1.add_batch(b)
    path = tmp_path / "day1.safetensors"
    save_snapshot(day1.learner.model, path)
    atomic_write_bytes(state_path(path), state_to_bytes(day1.learner.state_dict()))
    day2 = LearnerCore(
        load_description(ds.meta.robot),
        replace(CFG, start_from=str(path)),
        np.asarray(ds.meta.T_W_0),
    )
    assert isinstance(day2.learner, ContinualLearner)
    assert day2.learner.version == day1.learner.version == 2
    update = day2.add_batch(bs[3])  # frames re-identified from this batch, then learned
    assert update is not None and update.metrics.model_version == 3
    assert day2.learner.day_scale is not None  # carried: the network weighed on this batch
    assert 0.0 <= day2.learner.model.residual_gain <= 1.0
    assert len(day2.learner.memory) == len(day1.learner.memory) == 40
    assert day2.learner.day.fitted == 20  # the carry's batch
    for seq, b in enumerate(bs[:3], start=4):  # more of the day: its frames fitted again
        day2.add_batch(Batch(seq=seq, points=b.points))
    assert 40 < day2.learner.day.fitted <= len(day2.learner.day.x)
    again = core(ds)
    again.restore(day2.checkpoint())
    np.testing.assert_array_equal(again.learner.day.x, day2.learner.day.x)
    with pytest.raises(ConfigError, match="is for robot 'fanuc_m900ib700'"):
        LearnerCore(load_description("ur10"), replace(CFG, start_from=str(path)))
    from learner.carry import BEFORE_DAY

    server = open_session(BusConfig.loopback(free_port(), listen=True))
    stage = LearnerStage(
        server, "cell", ds.meta.robot, load_description(ds.meta.robot),
        replace(CFG, start_from=str(path)), np.asarray(ds.meta.T_W_0),
    )  # fmt: skip
    try:  # served before any of the day's points: drift-wide and unverified
        served = snapshot_from_bytes(stage.last_update.snapshot)
    finally:
        stage.close(10.0)
        server.close()
    assert served.unverified == BEFORE_DAY
    assert stage.last_update.header.model_version == day1.learner.version


def _later(batch, seq, hours, start=0):
    """``batch`` renumbered ``seq``, its points from ``start`` on ``hours`` later."""
    points = tuple(
        replace(p, t=p.t + 3600.0 * hours) if i >= start else p for i, p in enumerate(batch.points)
    )
    return Batch(seq=seq, points=points)


def test_a_pause_longer_than_a_night_starts_a_new_day_and_a_shorter_one_does_not(batches):
    """Points after a pause of more than ``new_day_after_h`` (4 h) are a new day: the model is
    carried into it on them (frames checked, the day's own test set), the batch's points before
    the pause learned first as the old day's; after a 1 h stop the day goes on as it was. Off
    by default: the same pause is one day."""
    ds, bs = batches
    off = core(ds)
    for b in bs[:3]:
        off.add_batch(b)
    off.add_batch(_later(bs[4], 4, 5.0, start=12))
    assert off.learner.day is None and not off.paused(off.last_t + 1e6)
    c = core(ds, NEW_DAYS)
    for b in bs[:3]:
        c.add_batch(b)
    shifted = bs[3].points[0].t - bs[2].points[-1].t
    c.add_batch(_later(bs[3], 3, 1.0 - shifted / 3600.0))
    assert c.learner.day is None and len(c.test_y) == 16
    t_last = c.last_t
    assert c.paused(t_last + 4.1 * 3600.0) and not c.paused(t_last + 3.9 * 3600.0)
    seen = c.learner.n_seen
    update = c.add_batch(_later(bs[4], 4, 5.0, start=12))  # the night falls after 12 points
    assert update is not None and c.learner.day is not None
    assert c.learner.day.fitted == 8 and c.learner.day_scale is not None
    day_test = holdout_mask(92, 8, 5).sum()  # every fifth point by arrival: 80 came before
    assert c.learner.n_seen == seen + 20 - holdout_mask(80, 12, 5).sum() - day_test
    assert len(c.test_y) == day_test  # the day's own test set
    assert c.last_seq == 4 and c.last_t == max(p.t for p in _later(bs[4], 4, 5.0, 12).points)
    again = core(ds, NEW_DAYS)
    again.restore(c.checkpoint())
    assert again.last_t == c.last_t


def test_a_model_restored_after_a_pause_is_served_unverified_until_the_days_first_batch(
    batches, tmp_path
):
    """A checkpoint restored the next morning is published as it answers before any of the
    new day's points (``learner.carry.before_day``): marked, so compensation flags it."""
    from learner.carry import BEFORE_DAY

    ds, bs = batches
    c = core(ds, NEW_DAYS)
    for b in bs[:3]:
        c.add_batch(b)
    now = c.last_t + 8 * 3600.0
    assert c.paused(now)
    served = snapshot_from_bytes(c.published(0.0, c.metrics(0.0, 0.0, 0.0), c.paused(now)).snapshot)
    assert served.unverified == BEFORE_DAY
    assert c.learner.model.unverified == ""  # the learner's own model is not touched
    same_day = snapshot_from_bytes(c.published(0.0, c.metrics(0.0, 0.0, 0.0)).snapshot)
    assert same_day.unverified == ""
    with pytest.raises(ConfigError, match="new_day_after_h must be > 0 h"):
        LearnerStageConfig(new_day_after_h=0.0)


def test_quarantined_points_are_neither_tested_nor_learned(batches):
    ds, bs = batches
    c = core(ds)
    for b in bs[:3]:
        c.add_batch(b)
    before = len(c.test_y)
    points = list(bs[3].points)
    bumped = set(range(5, 15))  # the tracker bumped by 50 mm for ten points
    for i in bumped:
        x, y, z = points[i].xyz
        points[i] = replace(points[i], xyz=(x + 0.05, y, z))
    update = c.add_batch(Batch(seq=3, points=tuple(points)))
    assert c.last_step.quarantined == 10 and update.metrics.quarantined == 10
    assert len(c.test_y) == before + 2  # of the 4 test points (every 5th), 2 were bumped
    X, _ = c.features(Batch(seq=3, points=tuple(points)))
    kept = {r.tobytes() for r in np.concatenate([c.test_x, c.learner.memory.x])}
    assert not kept & {X[i].tobytes() for i in bumped}
    assert c.metrics(0.0, 0.0, 0.0).quarantined == 10


def test_the_learner_stage_publishes_the_quarantine(batches):
    """On real loopback Zenoh: diagnostics count the quarantined points, metrics carry them."""
    ds, bs = batches
    robot, port = ds.meta.robot, free_port()
    server = open_session(BusConfig.loopback(port, listen=True))
    client = open_session(BusConfig.loopback(port, listen=False))
    got: dict[str, list] = {"diagnostics": [], "metrics": []}
    subs = [
        client.declare_subscriber(
            key("cell", robot, s), lambda x, s=s: got[s].append(x.payload.to_bytes())
        )
        for s in got
    ]
    log = io.StringIO()
    stage = LearnerStage(
        server, "cell", robot, load_description(robot), CFG, np.asarray(ds.meta.T_W_0),
        logger=JsonLogger(stream=log),
    )  # fmt: skip
    points = list(bs[3].points)
    for i in range(5, 15):
        x, y, z = points[i].xyz
        points[i] = replace(points[i], xyz=(x, y + 0.05, z))
    try:
        wait_subscribed(client, key("cell", robot, "batches"))
        for b in (*bs[:3], Batch(seq=3, points=tuple(points))):
            client.put(key("cell", robot, "batches"), encode(b))
        deadline = time.monotonic() + 120  # the first batch is too small for a model: 3 updates
        while len(got["metrics"]) < 3 and time.monotonic() < deadline:
            time.sleep(0.1)
        stage.publish_diagnostics()
        while not got["diagnostics"] and time.monotonic() < deadline:
            time.sleep(0.1)
    finally:
        stage.close(10.0)
        for sub in subs:
            sub.undeclare()
        client.close()
        server.close()
    assert decode(got["metrics"][-1], Metrics).quarantined == 10
    assert decode(got["diagnostics"][-1], Diagnostics).dropped["quarantined"] == 10
    assert '"event":"points_quarantined"' in log.getvalue()


def test_a_restarted_stage_republishes_under_its_description_name_and_sweeps(batches, tmp_path):
    """The stage's robot is the line's name for it; the model header names the description,
    after a restart from the checkpoint as on every update. A checkpoint write that a kill -9
    cut short is removed at the restart (and nothing else)."""
    ds, bs = batches
    c = core(ds)
    for b in bs[:2]:
        update = c.add_batch(b)
    write_checkpoint(c, tmp_path / "ck.safetensors")
    stale = tmp_path / ".ck.safetensors.k9x2.tmp"  # a kill -9 between write and rename
    stale.write_bytes(b"half a checkpoint")
    (tmp_path / ".other.safetensors.k9x2.tmp").write_bytes(b"not ours")
    log = io.StringIO()
    server = open_session(BusConfig.loopback(free_port(), listen=True))
    stage = LearnerStage(
        server, "cell", "arm-7", load_description(ds.meta.robot), CFG,
        np.asarray(ds.meta.T_W_0), checkpoint=tmp_path / "ck.safetensors",
        logger=JsonLogger(stream=log),
    )  # fmt: skip
    try:
        restored = stage.last_update.header
    finally:
        stage.close(10.0)
        server.close()
    assert restored.robot == update.header.robot == ds.meta.robot
    assert restored.model_version == update.header.model_version
    assert not stale.exists() and (tmp_path / ".other.safetensors.k9x2.tmp").exists()
    assert '"event":"stale_temporaries_removed"' in log.getvalue()


def test_the_learner_stage_trains_in_its_child_process_as_the_core_does_here(batches):
    """The stage's updates run in a child interpreter (``train_process``, the default) and give
    the weights the core gives in this process; closing the stage ends the child."""
    ds, bs = batches
    robot, port = ds.meta.robot, free_port()
    server = open_session(BusConfig.loopback(port, listen=True))
    client = open_session(BusConfig.loopback(port, listen=False))
    stage = LearnerStage(server, "cell", robot, load_description(robot), CFG, ds.meta.T_W_0)
    pid = stage.trainer.pid
    try:
        with open(f"/proc/{pid}/cmdline", "rb") as f:
            assert b"learner.train_process" in f.read()
        wait_subscribed(client, key("cell", robot, "batches"))
        for b in bs[:4]:
            client.put(key("cell", robot, "batches"), encode(b))
        deadline = time.monotonic() + 60
        while not stage.has_learned(0, 3) and time.monotonic() < deadline:
            time.sleep(0.05)
    finally:
        stage.close(10.0)
        client.close()
        server.close()
    here = core(ds)
    for b in bs[:4]:
        here.add_batch(b)
    assert stage.core.learner.version == here.learner.version == 3
    pairs = zip(
        stage.core.learner.model.net.state_dict().values(),
        here.learner.model.net.state_dict().values(),
        strict=True,
    )
    assert all(torch.equal(a, b) for a, b in pairs)
    assert stage.trainer.trained >= 3 and stage.trainer.failures == 0
    with pytest.raises(ChildProcessError):
        os.waitpid(pid, os.WNOHANG)  # ended and reaped


def test_a_model_file_as_the_base_stands_under_the_first_model_and_a_foreign_one_stops(
    batches, tmp_path
):
    """``continual.base`` a calibrated model file (``robocal calibrate --out``): the daemon's
    first model stands on it, its frame against this cell's tracker; a file of another robot
    stops the core at the start, naming it."""
    from kinematics.calibration import calibrate
    from kinematics.gap.model_file import ModelFile, model_to_toml

    ds, bs = batches
    result = calibrate(load_description(ds.meta.robot), ds)
    path = tmp_path / "calibrated.toml"
    path.write_text(
        model_to_toml(ModelFile(description=result.description, T_W_0=result.T_W_0, effects=()))
    )
    cfg = replace(CFG, continual=replace(CFG.continual, base=str(path)))
    c = LearnerCore(load_description(ds.meta.robot), cfg, np.asarray(ds.meta.T_W_0))
    c.add_batch(bs[0])
    update = c.add_batch(bs[1])
    base = c.learner.model.base
    assert update is not None and base.kind == "file" and base.note == str(path)
    X, Y = c.features(bs[2])
    base_mm = np.linalg.norm((Y - base.error(c.learner.model.spec, X, c.robot))[:, :3], axis=1)
    nominal_mm = np.linalg.norm(Y[:, :3], axis=1)
    assert base_mm.mean() < 0.3 * nominal_mm.mean()  # 0.52 against 2.56 mm: this cell's frame
    with pytest.raises(ConfigError, match="base file .* is for robot"):
        LearnerCore(load_description("ur10"), cfg)
