"""``kill -9`` while the learner trains its first model (issue 19: accepted points lost = 0):
nothing is checkpointed yet, but every batch the learner accepted is in its fsync'd accepted
log; the restart replays it, so the points the window batched are either learned or, for the
batches still in flight at the kill, reported lost — none of the accepted ones is missing."""

import io
import json
import signal
import threading
import time

import numpy as np
import pytest

from kinematics.description import load_description
from learner.config import ContinualConfig, ModelConfig, TrainConfig
from sim_sources.cell import simulate
from sim_sources.scenarios import get_scenario
from sim_sources.streaming import StreamingConfig
from stream.bus import BusConfig, alive_stages, free_port, open_session, publisher
from stream.learner_core import LearnerCore, LearnerStageConfig
from stream.log import JsonLogger
from stream.points import dataset_to_points
from stream.sources import SimCellSource
from stream.stages.learner_stage import LearnerStage, read_checkpoint
from stream.state import AcceptedLog
from tests.stream.conftest import daemon_config, kill_running, start_daemon, wait_for
from wire import Batch, decode, encode, key

pytestmark = pytest.mark.integration


def test_kill_9_during_the_first_training_loses_no_accepted_point(tmp_path):
    ds = simulate(get_scenario("paper"), 60, 31)
    robot, port = ds.meta.robot, free_port()
    cfg = tmp_path / "robocal.toml"
    fields = dict(
        port=port,
        robot=robot,
        T_W_0=ds.meta.T_W_0,
        state=tmp_path / "state",
        settings="shutdown_timeout_s = 8.0",
        memory=60,
        init=25,
        epochs_per_update=2,
    )
    daemon_config(cfg, **fields, neurons=256, init_epochs=10**6)  # trains "forever"
    state = tmp_path / "state"
    proc = start_daemon(cfg)
    client = open_session(BusConfig.loopback(port, listen=False))
    models = []
    restarted = None
    try:
        assert wait_for(lambda: len(alive_stages(client, "plant", 0.5)) >= 2)
        subs = [
            client.declare_subscriber(key("plant", robot, "model"), lambda s: models.append(1)),
        ]
        source = SimCellSource(client, "plant", robot, ds, StreamingConfig(period_s=1.0), speed=20)
        feeder = threading.Thread(target=source.start)
        feeder.start()
        log = AcceptedLog(state / f"{robot}.checkpoint.accepted")
        # 25 training points start the first model: the fourth batch (40 points, 32 after the
        # every-fifth hold-out) sets it training (after three, 24, a restart had none to learn)
        assert wait_for(lambda: len(log.records()) >= 4, 90)
        proc.send_signal(signal.SIGKILL)
        proc.wait(10)
        source.stop()
        feeder.join(30)
        assert models == [] and not (state / f"{robot}.checkpoint.safetensors").exists()
        accepted = sum(len(decode(r, Batch).points) for r in log.records())
        window = json.loads((state / f"{robot}.window.json").read_text())
        joined = window["points"]  # batched, or pending in the window's state

        for sub in subs:
            sub.undeclare()
        client.close()  # a fresh session: this test is about the points, not reconnecting

        daemon_config(cfg, **fields, neurons=8, init_epochs=5)
        restarted = start_daemon(cfg)
        client = open_session(BusConfig.loopback(port, listen=False))
        assert wait_for(lambda: len(alive_stages(client, "plant", 0.5)) >= 2)

        # the replayed log may publish the first model before this session hears it: a query
        # for the newest model finds it then
        def has_model() -> bool:
            got = client.get(key("plant", robot, "model"), timeout=1.0)
            return any(r.ok is not None for r in got)

        assert wait_for(has_model, 90), "no model after the restart"
        restarted.send_signal(signal.SIGTERM)
        assert restarted.wait(20) == 0
    finally:
        client.close()
        kill_running(proc, restarted)
    events = [json.loads(x) for x in restarted.stderr.read().splitlines() if x.startswith("{")]
    replayed = [e["points"] for e in events if e["event"] == "accepted_replayed"]
    lost = sum(e["lost"] for e in events if e["event"] == "points_lost")
    core = LearnerCore.__new__(LearnerCore)
    core.cfg, core.desc = LearnerStageConfig(), None
    read_checkpoint(core, state / f"{robot}.checkpoint.safetensors")
    assert replayed == [accepted] and accepted >= 30
    # every point the window joined before the kill is learned after the restart (the pending
    # ones in the batch sent at the stop) or reported lost (its batch was on the way)
    assert core.n_points + lost == joined and core.n_points >= accepted
    print(
        f"\nkill -9 in the first training: accepted {accepted} (0 checkpointed), replayed "
        f"{replayed[0]}, learned {core.n_points}, lost in flight {lost}, joined {joined}"
    )


def test_batches_sent_while_the_accepted_log_replays_are_learned_after_it(tmp_path):
    """A restart replays the accepted log on the stage's worker, after it has subscribed: the
    window's batches that arrive meanwhile (a replay that trains a model takes seconds, a
    carried day's fresh network about a minute) wait in the queue and are learned after the
    replayed ones, not lost on the bus."""
    ds = simulate(get_scenario("paper"), 120, 33)
    robot, port = ds.meta.robot, free_port()
    points = dataset_to_points(ds)
    epoch = int(time.time() * 1000) - 60_000
    batches = [
        Batch(seq=k, points=tuple(points[20 * k : 20 * k + 20]), epoch=epoch, first=20 * k)
        for k in range(6)
    ]
    checkpoint = tmp_path / "state" / "learner.checkpoint.safetensors"
    accepted = AcceptedLog(checkpoint.with_suffix(".accepted"))
    for b in batches[:3]:  # accepted before a kill -9, no checkpoint yet: the restart trains
        accepted.append(encode(b))
    cfg = LearnerStageConfig(
        model=ModelConfig(hidden_layers=2, neurons=64),
        train=TrainConfig(batch_size=8, early_stop_patience=10**6, patience_lr=10**6),
        continual=ContinualConfig(
            memory=100, batch=10, init=40, init_epochs=150, epochs_per_update=5
        ),
        holdout_every=5,
    )
    server = open_session(BusConfig.loopback(port, listen=True))
    client = open_session(BusConfig.loopback(port, listen=False))
    log = io.StringIO()
    stage: list[LearnerStage] = []
    args = dict(
        session=server, cell="plant", robot=robot, desc=load_description(robot), cfg=cfg,
        T_W_0=np.asarray(ds.meta.T_W_0), checkpoint=checkpoint, logger=JsonLogger(stream=log),
    )  # fmt: skip
    opening = threading.Thread(target=lambda: stage.append(LearnerStage(**args)))
    pub = publisher(client, key("plant", robot, "batches"))
    try:
        opening.start()
        assert wait_for(lambda: pub.matching_status.matching, 60)
        assert "accepted_replayed" not in log.getvalue(), "subscribed only after the replay"
        for b in batches[3:]:
            pub.put(encode(b))
        opening.join(60)
        done = lambda: all(stage[0].has_learned(epoch, b.seq) for b in batches)  # noqa: E731
        assert wait_for(done, 120), log.getvalue()[-2000:]
        assert '"event":"accepted_replayed"' in log.getvalue()
        core = stage[0].core
        assert core.n_points == 120 and stage[0].lost_points == 0
        assert stage[0].counter.accepted == 6 and dict(stage[0].counter.dropped) == {}
    finally:
        failure = stage[0].close(30) if stage else None
        client.close()
        server.close()
    assert failure is None
