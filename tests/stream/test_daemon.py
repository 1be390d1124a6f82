"""``robocal run`` as a real process: stages come alive, learn, and SIGTERM stops them cleanly
(checkpoint written, MCAP finished); a restart answers the model query from the checkpoint."""

import json
import signal
import time

import pytest
from mcap.reader import make_reader

from sim_sources.cell import simulate
from sim_sources.scenarios import get_scenario
from sim_sources.streaming import StreamingConfig
from stream.bus import BusConfig, free_port, open_session
from stream.learner_core import LearnerCore, LearnerStageConfig
from stream.sources import SimCellSource
from stream.stages.learner_stage import read_checkpoint
from tests.stream.conftest import daemon_config, kill_running, start_daemon, wait_alive
from wire import decode_model, key

pytestmark = pytest.mark.integration


def test_run_learns_stops_on_sigterm_and_restarts_from_its_checkpoint(tmp_path):
    ds = simulate(get_scenario("paper"), 41, 2)
    port = free_port()
    cfg = daemon_config(
        tmp_path / "robocal.toml",
        port=port,
        T_W_0=ds.meta.T_W_0,
        state=tmp_path,
        recorder=tmp_path / "plant.mcap",
        batch_size=20,
        neurons=16,
        memory=40,
        batch=20,
        epochs_per_update=5,
        init_epochs=20,
    )
    proc = start_daemon(cfg)
    client = open_session(BusConfig.loopback(port, listen=False))
    try:
        wait_alive(client, 3, proc)  # recorder, window, learner
        models = []
        robot = ds.meta.robot
        sub = client.declare_subscriber(
            key("plant", robot, "model"), lambda s: models.append(s.payload.to_bytes())
        )
        SimCellSource(client, "plant", robot, ds, StreamingConfig(period_s=1.0)).start()
        deadline = time.monotonic() + 30
        while len(models) < 2 and time.monotonic() < deadline:
            time.sleep(0.1)
        assert len(models) >= 2
        proc.send_signal(signal.SIGTERM)
        assert proc.wait(60) == 0
        logs = [
            json.loads(line) for line in proc.stderr.read().splitlines() if line.startswith("{")
        ]
        assert {"daemon_started", "model_published", "daemon_stopped"} <= {x["event"] for x in logs}
        assert (tmp_path / f"{robot}.checkpoint.safetensors").exists()
        # the window's partial batch, sent at the stop, is learned before the learner stops
        core = LearnerCore.__new__(LearnerCore)
        core.cfg, core.desc = LearnerStageConfig(), None
        read_checkpoint(core, tmp_path / f"{robot}.checkpoint.safetensors")
        joined = json.loads((tmp_path / f"{robot}.window.json").read_text())["points"]
        assert core.n_points == joined == len(ds)  # 41: two batches of 20 and one point
        with (tmp_path / "plant.mcap").open("rb") as f:
            summary = make_reader(f).get_summary()
        topics = {c.topic for c in summary.channels.values()}
        assert key("plant", robot, "model") in topics and key("plant", robot, "joints") in topics
        last_version = decode_model(models[-1])[0].model_version

        restarted = start_daemon(cfg)
        wait_alive(client, 3, restarted)
        replies = [r.ok for r in client.get(key("plant", robot, "model"), timeout=5.0)]
        assert decode_model(replies[0].payload.to_bytes())[0].model_version >= last_version
        restarted.send_signal(signal.SIGINT)
        assert restarted.wait(60) == 0
        sub.undeclare()
    finally:
        client.close()
        kill_running(proc, locals().get("restarted"))
