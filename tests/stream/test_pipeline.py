"""End to end over real Zenoh on loopback: simulated cell -> window -> learner -> model by query
-> compensation service; record -> replay; a stream with injected bad messages."""

import time
from dataclasses import dataclass, replace

import numpy as np
import pytest
import torch

from kinematics.model import RobotModel
from kinematics.transforms import pose_error
from learner.config import ContinualConfig, ModelConfig, TrainConfig
from learner.snapshot import snapshot_from_bytes
from sim_sources.cell import SimulatedCell, simulate
from sim_sources.scenarios import get_scenario
from sim_sources.streaming import StreamingConfig, cell_samples
from stream.bus import BusConfig, free_port, open_session
from stream.compensation import CompensationReply, CompensationRequest
from stream.config import DaemonConfig, RecorderConfig, RobotConfig
from stream.daemon import Daemon
from stream.learner_core import LearnerStageConfig
from stream.log import JsonLogger
from stream.mcap_io import SOURCE_STREAMS, recorded_samples
from stream.replay import replay_to_bus
from stream.sources import SimCellSource
from stream.window import Joiner, WindowConfig
from tests.stream.conftest import wait_subscribed
from wire import Diagnostics, JointSample, decode, decode_model, encode, key

pytestmark = pytest.mark.integration

N, SEED, CELL = 150, 0, "test"
STREAMING = StreamingConfig(period_s=1.0)
LEARNER = LearnerStageConfig(
    model=ModelConfig(hidden_layers=2, neurons=32),
    train=TrainConfig(batch_size=32),
    continual=ContinualConfig(memory=90, batch=45, init=40, epochs_per_update=15, init_epochs=120),
    holdout_every=10,
)


@dataclass
class Run:
    points: list[bytes]
    model_payload: bytes
    window_dropped: dict
    window_accepted: int
    replies: list[CompensationReply]
    test_x: np.ndarray
    errors: list[str]


@pytest.fixture(scope="module")
def campaign():
    torch.set_num_threads(1)
    return simulate(get_scenario("paper"), N, SEED)


def config(ds, port, mcap=None) -> DaemonConfig:
    return DaemonConfig(
        cell=CELL,
        bus=BusConfig.loopback(port, listen=True),
        robots=(
            RobotConfig(
                name=ds.meta.robot,
                description=ds.meta.robot,
                stages=("window", "learner", "compensation"),
                T_W_0=tuple(map(tuple, ds.meta.T_W_0)),
            ),
        ),
        window=WindowConfig(batch_size=LEARNER.continual.batch),
        learner=LEARNER,
        recorder=None if mcap is None else RecorderConfig(path=str(mcap), flush_interval_s=0.5),
    )


def requests(ds, index):
    temps = {c[5:]: float(ds.table[c].iloc[index]) for c in ds.table if c.startswith("temp_")}
    q = ds.q()[index]
    return CompensationRequest(
        q=tuple(q), temperatures=temps, deflection=tuple(ds.deflection()[index])
    )


def run_pipeline(ds, publish, mcap=None, compensate_rows=()) -> Run:
    """Start the daemon, let ``publish(session)`` stream into it, collect what came out."""
    port = free_port()
    log = JsonLogger(stream=open("/dev/null", "w"))  # noqa: SIM115
    daemon = Daemon(config(ds, port, mcap), logger=log).start()
    client = open_session(BusConfig.loopback(port, listen=False))
    robot = ds.meta.robot
    points: list[bytes] = []
    diagnostics: dict[str, Diagnostics] = {}

    def on_diagnostics(sample):
        d = decode(sample.payload.to_bytes(), Diagnostics)
        diagnostics[d.stage] = d

    subs = [
        client.declare_subscriber(
            key(CELL, robot, "points"), lambda s: points.append(s.payload.to_bytes())
        ),
        client.declare_subscriber(key(CELL, robot, "diagnostics"), on_diagnostics),
    ]
    try:
        wait_subscribed(client, *(key(CELL, robot, s) for s in SOURCE_STREAMS))
        daemon.end_of_stream({robot: publish(client)})
        time.sleep(0.2)
        (reply,) = [r.ok for r in client.get(key(CELL, robot, "model"), timeout=5.0)]
        replies = []
        for i in compensate_rows:
            got = list(
                client.get(
                    key(CELL, robot, "compensate"), payload=encode(requests(ds, i)), timeout=5.0
                )
            )
            replies.append(decode(got[0].ok.payload.to_bytes(), CompensationReply))
        errors = []
        if compensate_rows:  # bad requests get a one-line error; the service keeps answering
            good = encode(requests(ds, compensate_rows[0]))
            for payload in (b"{oops", encode(CompensationRequest(q=(0.0,) * 5)), good):
                got = list(client.get(key(CELL, robot, "compensate"), payload=payload, timeout=5))
                errors.append(got[0].err.payload.to_bytes().decode() if got[0].err else "ok")
        test_x = daemon.learners[robot].core.test_x
    finally:
        daemon.stop()  # the stages publish their final diagnostics
        time.sleep(0.3)
        for sub in subs:
            sub.undeclare()
        client.close()
    window = diagnostics["window"]
    return Run(
        points, reply.payload.to_bytes(), window.dropped, window.accepted, replies, test_x, errors
    )


@pytest.fixture(scope="module")
def clean(campaign, tmp_path_factory):
    mcap = tmp_path_factory.mktemp("rec") / "clean.mcap"
    robot = campaign.meta.robot

    def publish(session):
        source = SimCellSource(session, CELL, robot, campaign, STREAMING)
        source.start()
        return source.published

    held_out = list(range(9, N, 10))[:8]
    return run_pipeline(campaign, publish, mcap, held_out), mcap, held_out


def predictions(run: Run) -> np.ndarray:
    model = snapshot_from_bytes(decode_model(run.model_payload)[1])
    return model.predict(run.test_x).gamma


def test_end_to_end_model_by_query_and_compensation_reduces_true_error(campaign, clean):
    run, _, held_out = clean
    header, _ = decode_model(run.model_payload)
    assert len(run.points) == N and run.window_dropped == {}
    assert header.model_version >= 3 and header.n_seen == N - N // 10
    cell = SimulatedCell(get_scenario("paper"), N, SEED)
    nominal = RobotModel(cell.model.description)
    cond = cell.conditions(np.array(held_out))
    target = nominal.fk(cond.q)
    qc = np.array([r.q_corrected for r in run.replies])
    assert all(r.model_version == header.model_version for r in run.replies)
    assert run.errors[0].startswith("malformed") and run.errors[1].startswith("joint_count")
    assert run.errors[2] == "ok"
    before = np.linalg.norm(pose_error(cell.truth.poses(cond), target)[:, :3], axis=1)
    after_cond = replace(cond, q=qc)
    after = np.linalg.norm(pose_error(cell.truth.poses(after_cond), target)[:, :3], axis=1)
    assert after.mean() < 0.6 * before.mean()


def test_record_then_replay_gives_the_same_points_and_model(campaign, clean):
    run, mcap, _ = clean
    offline = Joiner(WindowConfig(batch_size=LEARNER.continual.batch))
    points = [p for _, s in recorded_samples(mcap) for p in offline.push(s)] + offline.flush()
    assert [encode(p) for p in points] == run.points
    replayed = run_pipeline(
        campaign, lambda session: replay_to_bus(mcap, session, speed=None).published
    )
    assert replayed.points == run.points
    np.testing.assert_array_equal(predictions(replayed), predictions(run))


class FaultySource(SimCellSource):
    """The clean campaign with one bad message of each kind injected in line."""

    BAD = {
        "malformed": ("joints", b"{not json"),
        "schema": ("tracker", b'{"schema":"robocal.other","version":1}'),
        "version": ("temperature", b'{"schema":"robocal.temperature","version":7}'),
        "non_finite": ("joints", encode(JointSample(seq=10**6, t=1.0, q=(float("nan"),) * 6))),
        "out_of_range": ("joints", encode(JointSample(seq=10**6, t=1.0, q=(50.0,) * 6))),
        "joint_count": ("joints", encode(JointSample(seq=10**6, t=1.0, q=(0.0,) * 5))),
    }

    def run(self):
        samples = list(cell_samples(self.ds, self.cfg))
        for i, s in enumerate(samples):
            self.publish(s)
            if i == 3000:
                for stream, payload in self.BAD.values():
                    self.publish_raw(stream, payload)
            if i == 5000 and isinstance(s, JointSample):
                self.publish(s)  # duplicate
                self.publish(replace(s, seq=s.seq + 10**6, t=s.t - 1.0))  # clock went back


def test_bad_messages_are_counted_and_leave_the_model_untouched(campaign, clean):
    run, _, _ = clean
    robot = campaign.meta.robot

    def publish(session):
        source = FaultySource(session, CELL, robot, campaign, STREAMING)
        source.start()
        return source.published

    faulty = run_pipeline(campaign, publish)
    expected = {reason: 1 for reason in FaultySource.BAD}
    expected |= {"duplicate": 1, "time_backwards": 1}
    assert faulty.window_dropped == expected
    assert faulty.points == run.points
    np.testing.assert_array_equal(predictions(faulty), predictions(run))
