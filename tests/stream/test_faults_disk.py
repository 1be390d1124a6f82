"""A full disk and a read-only state directory under a running ``robocal run`` (issue 19): the
state directory is a 2 MB tmpfs that the test fills or remounts read-only mid-stream. With
``on_disk_full = "stop"`` the daemon ends with one ``stage_failed`` line and exit 2, no
temporary file left, the last checkpoint readable and the MCAP (on another disk) finished; with
``"wait"`` it says so in one line, goes on, and resumes its checkpoints once the directory is
writable again. Needs root (mount); skipped with the reason otherwise."""

import json
import signal
import subprocess
import threading
import time
from pathlib import Path

import pytest
from mcap.reader import make_reader

from sim_sources.cell import simulate
from sim_sources.scenarios import get_scenario
from sim_sources.streaming import StreamingConfig
from stream.bus import BusConfig, alive_stages, free_port, open_session
from stream.learner_core import LearnerCore, LearnerStageConfig
from stream.sources import SimCellSource
from stream.stages.learner_stage import read_checkpoint
from tests.stream.conftest import daemon_config, fill, kill_running, start_daemon, wait_for
from wire import key

pytestmark = pytest.mark.integration


def run_cell(tmp_path, state: Path, policy: str, fault, recover=None):
    """Start the daemon, stream a cell, inject ``fault(state)`` after the first checkpoint,
    then ``recover(state)`` (if given) and SIGTERM; returns exit code, log events, models
    seen after the fault and after recovery."""
    ds = simulate(get_scenario("paper"), 200, 21)
    robot, port = ds.meta.robot, free_port()
    cfg = daemon_config(
        tmp_path / "robocal.toml",
        port=port,
        T_W_0=ds.meta.T_W_0,
        state=state,
        robot=robot,
        recorder=tmp_path / "plant.mcap",
        settings=f'shutdown_timeout_s = 5.0\non_disk_full = "{policy}"',
        epochs_per_update=2,
        init_epochs=5,
    )
    proc = start_daemon(cfg)
    client = open_session(BusConfig.loopback(port, listen=False))
    models: list[float] = []
    ckpt = state / f"{robot}.checkpoint.safetensors"
    source = SimCellSource(
        client, "plant", robot, ds, StreamingConfig(joint_rate_hz=10.0, period_s=1.0), speed=20
    )
    feeder = threading.Thread(target=source.start)
    marks = {}
    try:
        assert wait_for(
            lambda: len(alive_stages(client, "plant", 0.5)) >= 3 or proc.poll() is not None
        )
        sub = client.declare_subscriber(
            key("plant", robot, "model"), lambda s: models.append(time.monotonic())
        )
        feeder.start()
        assert wait_for(lambda: ckpt.exists() and len(models) >= 2), "no checkpoint"
        marks["before"] = ckpt.read_bytes()
        fault(state)
        marks["fault"] = time.monotonic()
        if recover is None:
            code = proc.wait(60)
        else:
            time.sleep(1.5)  # the daemon waits, its queues fill
            assert proc.poll() is None, "the daemon ended although told to wait"
            recover(state)
            marks["recovered"] = time.monotonic()
            n = len(models)
            assert wait_for(lambda: len(models) > n + 1, 60), "no model after recovery"
            proc.send_signal(signal.SIGTERM)
            code = proc.wait(20)
        sub.undeclare()
    finally:
        source.stop()
        if feeder.is_alive():
            feeder.join(30)
        client.close()
        kill_running(proc)
    events = [json.loads(x) for x in proc.stderr.read().splitlines() if x.startswith("{")]
    return code, events, ckpt, marks, models


def restorable(ckpt: Path) -> int:
    """The point count of a checkpoint (it reads back)."""
    core = LearnerCore.__new__(LearnerCore)
    core.cfg, core.desc = LearnerStageConfig(), None
    read_checkpoint(core, ckpt)
    return core.n_points


def test_a_full_disk_stops_the_daemon_with_one_line_and_exit_2(tmp_path, small_fs):
    code, events, ckpt, _, _ = run_cell(tmp_path, small_fs, "stop", fill)
    failed = [e for e in events if e["event"] == "stage_failed"]
    assert code == 2 and len(failed) == 1, (code, failed)
    assert "[ENOSPC]" in failed[0]["cause"]
    assert [p.name for p in small_fs.iterdir() if p.name.startswith(".")] == []  # no temp file
    assert restorable(ckpt) > 0  # the last good checkpoint reads back
    with (tmp_path / "plant.mcap").open("rb") as f:
        assert make_reader(f).get_summary().statistics.message_count > 0  # finished, footer
    print(f"\nfull disk (stop): exit {code}, one line: {failed[0]['cause']}")


def remount(state: Path, mode: str) -> None:
    """Remount ``state`` ``ro`` or ``rw``. A write in flight (the daemon's stages write all the
    time) fails a read-only remount with "mount point is busy": tried again a moment later,
    it is the same fault."""
    for _ in range(100):
        cmd = ["mount", "-o", f"remount,{mode}", str(state)]
        done = subprocess.run(cmd, capture_output=True, text=True)
        if done.returncode == 0 or "busy" not in done.stderr:
            break
        time.sleep(0.02)
    assert done.returncode == 0, f"remount,{mode} {state}: {done.stderr.strip()}"


def test_a_read_only_state_dir_with_wait_pauses_then_resumes(tmp_path, small_fs):
    def read_only(state):
        remount(state, "ro")

    def writable(state):
        remount(state, "rw")

    code, events, ckpt, marks, models = run_cell(
        tmp_path, small_fs, "wait", read_only, recover=writable
    )
    names = [e["event"] for e in events]
    unwritable = [e for e in events if e["event"] == "state_unwritable"]
    assert code == 0 and "stage_failed" not in names, (code, unwritable)
    assert 1 <= len(unwritable) <= 2 and all("[EROFS]" in e["cause"] for e in unwritable)
    assert "state_writable" in names
    assert [p.name for p in small_fs.iterdir() if p.name.startswith(".")] == []
    assert restorable(ckpt) > 0
    after = sum(t > marks["recovered"] for t in models)
    print(f"\nread-only (wait): exit {code}, {len(unwritable)} line(s) while waiting, "
          f"{after} models after the directory came back")  # fmt: skip


def test_on_disk_full_must_be_stop_or_wait():
    from kinematics.errors import ConfigError
    from stream.config import config_from_dict

    with pytest.raises(ConfigError, match="on_disk_full"):
        config_from_dict({"on_disk_full": "retry", "robot": [{"name": "r", "description": "ur10"}]})


def test_a_temporary_left_by_a_read_only_remount_goes_once_the_write_succeeds(tmp_path, small_fs):
    """The directory turns read-only between the atomic writer's temporary and its rename: the
    writer cannot delete the temporary either; the stage's retry, once it succeeds, does."""
    import io

    from kinematics.dataset import atomic_write
    from stream.log import JsonLogger
    from stream.stages.window_stage import WindowStage
    from stream.window import WindowConfig

    session = open_session(BusConfig.loopback(free_port(), listen=True))
    stage = WindowStage(session, "disk", "r1", WindowConfig(), JsonLogger(stream=io.StringIO()))
    stage.on_disk_full, stage.retry_s = "wait", 0.05
    path, tries = small_fs / "state.json", []

    def whole(tmp: str) -> None:
        Path(tmp).write_bytes(b"{}")

    def cut_by_remount(tmp: str) -> None:
        whole(tmp)
        remount(small_fs, "ro")

    def write() -> None:
        tries.append(len(tries))
        if len(tries) == 2:
            remount(small_fs, "rw")
        atomic_write(path, cut_by_remount if len(tries) == 1 else whole)

    try:
        stage.persist(write, "window state", path)
    finally:
        subprocess.run(["mount", "-o", "remount,rw", str(small_fs)], check=False)
        stage.close()
        session.close()
    assert len(tries) == 2
    assert sorted(p.name for p in small_fs.iterdir()) == ["state.json"]
