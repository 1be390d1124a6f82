"""``kill -9`` while the learner trains its first model (issue 19: accepted points lost = 0):
nothing is checkpointed yet, but every batch the learner accepted is in its fsync'd accepted
log; the restart replays it, so the points the window batched are either learned or, for the
batches still in flight at the kill, reported lost — none of the accepted ones is missing."""

import json
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

import pytest

from sim_sources.cell import simulate
from sim_sources.scenarios import get_scenario
from sim_sources.streaming import StreamingConfig
from stream.bus import BusConfig, alive_stages, free_port, open_session
from stream.learner_core import LearnerCore, LearnerStageConfig
from stream.sources import SimCellSource
from stream.state import AcceptedLog
from wire import Batch, decode, key

pytestmark = pytest.mark.integration

CONFIG = """
cell = "plant"
checkpoint_dir = "{dir}/state"
shutdown_timeout_s = 8.0

[bus]
mode = "peer"
listen = ["tcp/127.0.0.1:{port}"]
multicast_scouting = false

[[robot]]
name = "{robot}"
description = "{robot}"
stages = ["window", "learner"]
T_W_0 = {T_W_0}

[window]
batch_size = 10

[learner]
holdout_every = 5

[learner.model]
hidden_layers = 1
neurons = {neurons}

[learner.continual]
memory = 60
batch = 10
init = 25
epochs_per_update = 2
init_epochs = {init_epochs}
"""


def start(cfg: Path) -> subprocess.Popen:
    exe = str(Path(sys.executable).with_name("robocal"))
    return subprocess.Popen([exe, "run", "--config", str(cfg)], stderr=subprocess.PIPE, text=True)


def wait_for(cond, timeout: float = 60.0) -> bool:
    deadline = time.monotonic() + timeout
    while not cond() and time.monotonic() < deadline:
        time.sleep(0.05)
    return cond()


def test_kill_9_during_the_first_training_loses_no_accepted_point(tmp_path):
    ds = simulate(get_scenario("paper"), 60, 31)
    robot, port = ds.meta.robot, free_port()
    cfg = tmp_path / "robocal.toml"
    fields = dict(dir=tmp_path, port=port, robot=robot, T_W_0=json.dumps(ds.meta.T_W_0))
    cfg.write_text(CONFIG.format(**fields, neurons=256, init_epochs=10**6))  # trains "forever"
    state = tmp_path / "state"
    proc = start(cfg)
    client = open_session(BusConfig.loopback(port, listen=False))
    batches, models = [], []
    restarted = None
    try:
        assert wait_for(lambda: len(alive_stages(client, "plant", 0.5)) >= 2)
        subs = [
            client.declare_subscriber(key("plant", robot, "batches"), lambda s: batches.append(1)),
            client.declare_subscriber(key("plant", robot, "model"), lambda s: models.append(1)),
        ]
        source = SimCellSource(client, "plant", robot, ds, StreamingConfig(period_s=1.0), speed=20)
        feeder = threading.Thread(target=source.start)
        feeder.start()
        log = AcceptedLog(state / f"{robot}.checkpoint.accepted")
        # 25 points start the first model: the third batch sets it training, more queue behind
        assert wait_for(lambda: len(log.records()) >= 3 and len(batches) >= 4, 90)
        proc.send_signal(signal.SIGKILL)
        proc.wait(10)
        source.stop()
        feeder.join(30)
        assert models == [] and not (state / f"{robot}.checkpoint.safetensors").exists()
        accepted = sum(len(decode(r, Batch).points) for r in log.records())
        window = json.loads((state / f"{robot}.window.json").read_text())
        joined = window["points"]  # batched, or pending in the window's state

        cfg.write_text(CONFIG.format(**fields, neurons=8, init_epochs=5))
        restarted = start(cfg)
        assert wait_for(lambda: len(models) >= 1, 90), "no model after the restart"
        restarted.send_signal(signal.SIGTERM)
        assert restarted.wait(20) == 0
        for sub in subs:
            sub.undeclare()
    finally:
        client.close()
        for p in (proc, restarted):
            if p is not None and p.poll() is None:
                p.kill()
    events = [json.loads(x) for x in restarted.stderr.read().splitlines() if x.startswith("{")]
    replayed = [e["points"] for e in events if e["event"] == "accepted_replayed"]
    lost = sum(e["lost"] for e in events if e["event"] == "points_lost")
    core = LearnerCore.__new__(LearnerCore)
    core.cfg, core.desc = LearnerStageConfig(), None
    LearnerCore.restore(core, state / f"{robot}.checkpoint.safetensors")
    assert replayed == [accepted] and accepted >= 30
    # every point the window joined before the kill is learned after the restart (the pending
    # ones in the batch sent at the stop) or reported lost (its batch was on the way)
    assert core.n_points + lost == joined and core.n_points >= accepted
    print(
        f"\nkill -9 in the first training: accepted {accepted} (0 checkpointed), replayed "
        f"{replayed[0]}, learned {core.n_points}, lost in flight {lost}, joined {joined}"
    )
