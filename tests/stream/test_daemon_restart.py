"""``robocal run`` as a real process, killed and restarted: ``kill -9`` mid-stream and a restart
drop 0 batches as duplicates and report the points lost; the old recording stays byte for byte
and readable, the new one is a separate file. A state directory that becomes unusable stops the
daemon with one line and exit 2, the last checkpoint intact and no temporary file left; a
read-only state directory at start is one line and exit 2."""

import hashlib
import json
import signal
import threading
import time
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
from mcap.reader import make_reader

from sim_sources.cell import simulate
from sim_sources.scenarios import get_scenario
from sim_sources.streaming import StreamingConfig, cell_samples
from stream.bus import BusConfig, free_port, open_session
from stream.learner_core import LearnerCore, LearnerStageConfig
from stream.mcap_io import read_mcap
from stream.sources import SimCellSource
from stream.stages.learner_stage import read_checkpoint
from stream.state import AcceptedLog
from tests.stream.conftest import daemon_config, kill_running, start_daemon, wait_alive
from wire import Batch, Diagnostics, decode, key

pytestmark = pytest.mark.integration


class Shifted(SimCellSource):
    """The campaign ``offset_s`` later; stops publishing when asked."""

    offset_s = 0.0

    def run(self):
        for s in cell_samples(self.ds, self.cfg):
            if not self.running:
                return
            self.publish(replace(s, t=s.t + self.offset_s))


def logs(proc) -> list[dict]:
    return [json.loads(x) for x in proc.stderr.read().splitlines() if x.startswith("{")]


def sha(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


def write_config(tmp_path, port, ds, state=None) -> Path:
    return daemon_config(
        tmp_path / "robocal.toml",
        port=port,
        T_W_0=ds.meta.T_W_0,
        state=state or tmp_path / "state",
        recorder=tmp_path / "plant.mcap",
        settings="shutdown_timeout_s = 5.0",
    )


def test_kill_9_mid_stream_then_restart_continues_without_duplicates(tmp_path):
    ds = simulate(get_scenario("paper"), 50, 5)
    robot, port = ds.meta.robot, free_port()
    cfg = write_config(tmp_path, port, ds)
    state = tmp_path / "state"
    proc = start_daemon(cfg)
    client = open_session(BusConfig.loopback(port, listen=False))
    restarted = None
    try:
        wait_alive(client, 3, proc)
        models, points, diags = [], [], {}
        subs = [
            client.declare_subscriber(key("plant", robot, "model"), lambda s: models.append(1)),
            client.declare_subscriber(key("plant", robot, "points"), lambda s: points.append(1)),
            client.declare_subscriber(
                key("plant", robot, "diagnostics"),
                lambda s: diags.update({(d := decode(s.payload.to_bytes(), Diagnostics)).stage: d}),
            ),
        ]
        source = Shifted(client, "plant", robot, ds, StreamingConfig(period_s=1.0))
        feeder = threading.Thread(target=source.start)
        feeder.start()
        deadline = time.monotonic() + 60
        while len(models) < 2 and time.monotonic() < deadline:
            time.sleep(0.02)
        assert len(models) >= 2
        time.sleep(0.1)  # more points after the last checkpoint
        proc.send_signal(signal.SIGKILL)
        proc.wait(10)
        source.stop()
        feeder.join()
        emitted_before_kill = len(points)
        old = tmp_path / "plant.mcap"
        old_sha = sha(old)
        window_state = json.loads((state / f"{robot}.window.json").read_text())
        core = LearnerCore.__new__(LearnerCore)  # read the checkpoint as the restart will
        core.cfg = LearnerStageConfig()
        core.desc = None
        read_checkpoint(core, state / f"{robot}.checkpoint.safetensors")
        ((epoch, (last_seq, next_point)),) = core.windows.items()
        assert epoch == window_state["epoch"] and last_seq < window_state["next_seq"]
        # accepted and kept: the checkpoint, the learner's accepted log after it, the window's
        # batch being filled; what the restart must report lost: the rest (batches in flight)
        logged = [
            decode(r, Batch) for r in AcceptedLog(state / f"{robot}.checkpoint.accepted").records()
        ]
        # killed between writing the checkpoint and clearing the log: what it holds is not new
        logged_points = sum(len(b.points) for b in logged if b.seq > last_seq)
        pending = len(window_state["pending"])
        expect_lost = window_state["points"] - pending - next_point - logged_points
        assert expect_lost >= 0 and emitted_before_kill <= window_state["points"]

        restarted = start_daemon(cfg)
        wait_alive(client, 3, restarted)
        n_models = len(models)
        later = Shifted(client, "plant", robot, simulate(get_scenario("paper"), 25, 6), source.cfg)
        later.offset_s = 100.0
        later.start()
        deadline = time.monotonic() + 60
        while len(models) < n_models + 2 and time.monotonic() < deadline:
            time.sleep(0.05)  # the restored model, then one learned after the restart
        assert len(models) >= n_models + 2, "the restarted learner published no new model"
        restarted.send_signal(signal.SIGTERM)
        assert restarted.wait(15) == 0
        time.sleep(0.3)
        events = logs(restarted)
        for sub in subs:
            sub.undeclare()
    finally:
        client.close()
        kill_running(proc, restarted)
    learner_diag = diags["learner"]
    assert learner_diag.dropped.get("duplicate", 0) == 0
    lost = [e for e in events if e["event"] == "points_lost"]
    if expect_lost:
        assert [e["lost"] for e in lost] == [expect_lost]
        assert learner_diag.dropped.get("lost") == expect_lost
    else:
        assert lost == []
    restored = next(e for e in events if e["event"] == "checkpoint_restored")
    assert restored["windows"][str(epoch)]["next_point"] == next_point
    replayed = [e["points"] for e in events if e["event"] == "accepted_replayed"]
    assert replayed == ([logged_points] if logged_points else [])
    resumed = next(e for e in events if e["event"] == "window_state")
    assert resumed["pending"] == pending and resumed["points"] == window_state["points"]
    # the old recording: untouched and readable up to its last flush; the new one: separate
    assert sha(old) == old_sha
    assert sum(1 for _ in read_mcap(old)) > 0
    new = tmp_path / "plant.1.mcap"
    started = next(e for e in events if e["event"] == "daemon_started")
    assert started["recordings"]["mcap"] == str(new)
    with new.open("rb") as f:
        assert make_reader(f).get_summary().statistics.message_count > 0
    print(f"\nrestart: duplicates 0, lost reported {expect_lost}, emitted before kill "
          f"{emitted_before_kill}, checkpointed {next_point}, replayed from the accepted log "
          f"{logged_points}, kept pending in the window {pending}")  # fmt: skip


def test_a_state_dir_that_goes_away_stops_the_daemon_with_one_line_and_exit_2(tmp_path):
    ds = simulate(get_scenario("paper"), 60, 7)
    robot, port = ds.meta.robot, free_port()
    cfg = write_config(tmp_path, port, ds)
    state = tmp_path / "state"
    ckpt = state / f"{robot}.checkpoint.safetensors"
    proc = start_daemon(cfg)
    client = open_session(BusConfig.loopback(port, listen=False))
    try:
        wait_alive(client, 3, proc)
        source = Shifted(client, "plant", robot, ds, StreamingConfig(period_s=1.0))
        feeder = threading.Thread(target=source.start)
        feeder.start()
        deadline = time.monotonic() + 60
        while not ckpt.exists() and time.monotonic() < deadline:
            time.sleep(0.01)
        assert ckpt.exists()
        state.rename(tmp_path / "state.old")  # the directory is gone: a file is in its place
        state.write_text("not a directory")
        t0 = time.monotonic()
        code = proc.wait(20)
        took = time.monotonic() - t0
        source.stop()
        feeder.join()
    finally:
        client.close()
        kill_running(proc)
    events = logs(proc)
    failed = [e for e in events if e["event"] == "stage_failed"]
    assert code == 2 and took < 10 and len(failed) == 1, (code, took, failed)
    assert failed[0]["stage"] in ("learner", "window") and "[E" in failed[0]["cause"]
    old_dir = tmp_path / "state.old"
    assert [p.name for p in old_dir.iterdir() if p.name.startswith(".")] == []
    core = LearnerCore.__new__(LearnerCore)
    core.cfg, core.desc = LearnerStageConfig(), None
    read_checkpoint(core, old_dir / ckpt.name)  # the last good checkpoint reads back
    with (tmp_path / "plant.mcap").open("rb") as f:
        assert make_reader(f).get_summary() is not None  # MCAP finished with its footer


def test_an_unwritable_state_dir_at_start_is_one_line_and_exit_2(tmp_path):
    ds = simulate(get_scenario("paper"), 5, 0)
    blocker = tmp_path / "file"
    blocker.write_text("x")
    cfg = write_config(tmp_path, free_port(), ds, state=blocker / "state")
    proc = start_daemon(cfg)
    assert proc.wait(60) == 2
    err = proc.stderr.read().strip().splitlines()
    assert len(err) == 1 and err[0].startswith("robocal: error: checkpoint_dir"), err


def test_sigterm_while_the_learner_is_busy_ends_the_daemon_within_10_s(tmp_path):
    ds = simulate(get_scenario("paper"), 30, 8)
    robot, port = ds.meta.robot, free_port()
    cfg = write_config(tmp_path, port, ds)
    busy = cfg.read_text().replace("init_epochs = 10", "init_epochs = 1000000")
    cfg.write_text(busy.replace("neurons = 8", "neurons = 256"))
    proc = start_daemon(cfg)
    client = open_session(BusConfig.loopback(port, listen=False))
    try:
        wait_alive(client, 3, proc)
        batches = []
        sub = client.declare_subscriber(key("plant", robot, "batches"), lambda s: batches.append(1))
        Shifted(client, "plant", robot, ds, StreamingConfig(period_s=1.0)).start()
        deadline = time.monotonic() + 30
        while len(batches) < 2 and time.monotonic() < deadline:
            time.sleep(0.05)
        assert len(batches) >= 2  # the learner is training its first model, the next waits
        time.sleep(0.5)
        t0 = time.monotonic()
        proc.send_signal(signal.SIGTERM)
        code = proc.wait(15)
        took = time.monotonic() - t0
        sub.undeclare()
    finally:
        client.close()
        kill_running(proc)
    events = {e["event"] for e in logs(proc)}
    assert code == 0 and took < 10.0, (code, took)
    assert {"signal_received", "daemon_stopped"} <= events
    with (tmp_path / "plant.mcap").open("rb") as f:
        assert make_reader(f).get_summary() is not None


def test_a_base_file_of_another_robot_stops_the_daemon_with_one_line_and_exit_2(tmp_path):
    """``[learner.continual] base`` a model file: one of another robot (a UR10's on the Fanuc
    cell) stops ``robocal run`` at the start, naming the mismatch."""
    from kinematics.description import load_description
    from kinematics.gap.model_file import ModelFile, model_to_toml

    path = tmp_path / "ur10.toml"
    path.write_text(
        model_to_toml(ModelFile(description=load_description("ur10"), T_W_0=np.eye(4), effects=()))
    )
    cfg = daemon_config(
        tmp_path / "robocal.toml", port=free_port(), T_W_0=np.eye(4), state=tmp_path, base=str(path)
    )
    proc = start_daemon(cfg)
    assert proc.wait(60) == 2
    err = [x for x in proc.stderr.read().strip().splitlines() if not x.startswith("{")]
    assert len(err) == 1 and err[0].startswith("robocal: error: base file"), err
    assert "is for robot 'ur10'" in err[0]
