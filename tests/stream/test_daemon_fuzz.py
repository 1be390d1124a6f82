"""No message takes the daemon down or over: hypothesis publishes generated bad messages (wrong
types, huge and nested payloads, extreme timestamps and sequence numbers, wrong names and
frames, foreign and forged models) on every topic of a running daemon on loopback Zenoh, then
good data. After each message no stage has died and every query is answered; afterwards the
daemon still emits points and models, compensation uses the genuine model, and it stops within
10 s with its MCAP finished."""

import json
import time
from dataclasses import dataclass, field, replace

import numpy as np
import pytest
import torch
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from mcap.reader import make_reader
from safetensors.torch import load as st_load
from safetensors.torch import save as st_save

from kinematics.description import load_description
from learner.config import ContinualConfig, ModelConfig, TrainConfig
from learner.features import feature_spec
from learner.model import ErrorModel
from learner.snapshot import snapshot_meta, snapshot_to_bytes
from sim_sources.cell import simulate
from sim_sources.scenarios import get_scenario
from sim_sources.streaming import StreamingConfig, cell_samples
from stream.bus import BusConfig, free_port, open_session, publisher
from stream.compensation import CompensationReply, CompensationRequest
from stream.config import RecorderConfig
from stream.daemon import Daemon
from stream.demo import demo_config
from stream.learner_core import LearnerStageConfig
from stream.log import JsonLogger
from stream.sources import SimCellSource
from stream.window import WindowConfig
from tests.stream.conftest import wait_for
from tests.stream.wire_examples import DIAGNOSTICS, METRICS
from wire import (
    Batch,
    DataPoint,
    Diagnostics,
    JointSample,
    ModelHeader,
    TemperatureSample,
    TrackerSample,
    decode,
    decode_model,
    encode_model,
    key,
    to_dict,
)

pytestmark = pytest.mark.integration

CELL = "fuzz"
CODES = ("joint_limits", "quaternion", "unreachable", "solver", "residual", "corrected_limits")
SMALL = LearnerStageConfig(
    model=ModelConfig(hidden_layers=1, neurons=16),
    train=TrainConfig(batch_size=16),
    continual=ContinualConfig(memory=40, batch=20, init=10, epochs_per_update=5, init_epochs=20),
    holdout_every=5,
)
#: What a run found, for BENCHMARKS.md (printed at the end with -s).
TALLY = {"cases": 0, "queries": 0, "stage_deaths": 0, "hangs": 0}


@dataclass
class Live:
    daemon: Daemon
    client: object
    robot: str
    ds: object
    models: list = field(default_factory=list)
    points: list = field(default_factory=list)
    diagnostics: dict = field(default_factory=dict)
    templates: dict = field(default_factory=dict)
    forged_models: list = field(default_factory=list)
    pubs: dict = field(default_factory=dict)


@pytest.fixture(scope="module")
def live(tmp_path_factory):
    torch.set_num_threads(1)
    d = tmp_path_factory.mktemp("fuzz")
    ds = simulate(get_scenario("paper"), 40, 3)
    robot = ds.meta.robot
    port = free_port()
    cfg = replace(  # the demo's daemon (every stage, loopback), smaller and flushing often
        demo_config(d, CELL, robot, np.asarray(ds.meta.T_W_0), port),
        window=WindowConfig(batch_size=20),
        learner=SMALL,
        recorder=RecorderConfig(path=str(d / "fuzz.mcap"), flush_interval_s=0.2),
        checkpoint_dir=str(d / "state"),
        shutdown_timeout_s=7.0,
    )
    log = (d / "log.jsonl").open("w")
    daemon = Daemon(cfg, logger=JsonLogger(stream=log)).start()
    client = open_session(BusConfig.loopback(port, listen=False))
    run = Live(daemon, client, robot, ds)
    subs = [
        client.declare_subscriber(
            key(CELL, robot, "model"), lambda s: run.models.append(s.payload.to_bytes())
        ),
        client.declare_subscriber(
            key(CELL, robot, "points"), lambda s: run.points.append(s.payload.to_bytes())
        ),
        client.declare_subscriber(
            key(CELL, robot, "diagnostics"),
            lambda s: run.diagnostics.update(
                {(d := decode(s.payload.to_bytes(), Diagnostics)).stage: d}
            ),
        ),
    ]
    time.sleep(0.5)
    SimCellSource(client, CELL, robot, ds, StreamingConfig(period_s=1.0)).start()
    assert wait_for(lambda: len(run.models) >= 1, 30.0), "no model from the clean stream"
    run.templates = templates(ds, run.models[-1])
    run.forged_models = forged_models(run.models[-1], robot)
    yield run
    for sub in subs:
        sub.undeclare()
    for pub in run.pubs.values():
        pub.undeclare()
    if daemon.stages:
        daemon.stop(timeout_s=7.0)
    client.close()
    log.close()


def templates(ds, model_payload) -> dict:
    """A genuine-looking dict per JSON topic, to mutate one field at a time."""
    samples = list(cell_samples(ds, StreamingConfig(period_s=1.0)))
    joint = next(s for s in samples if isinstance(s, JointSample))
    tracker = next(s for s in samples if isinstance(s, TrackerSample))
    temp = next(s for s in samples if isinstance(s, TemperatureSample))
    point = replace(DataPoint.join(joint, tracker, temp), seq=5)
    header = decode_model(model_payload)[0]
    return {
        "joints": to_dict(joint),
        "tracker": to_dict(tracker),
        "temperature": to_dict(temp),
        "points": to_dict(point),
        "batches": to_dict(Batch(seq=1000, points=(point, point), epoch=1, first=0)),
        "metrics": to_dict(replace(METRICS, model_version=header.model_version)),
        "diagnostics": to_dict(DIAGNOSTICS),
        "compensate": {
            "schema": CompensationRequest.SCHEMA,
            "version": 1,
            **{k: v for k, v in to_dict(CompensationRequest(q=joint.q)).items() if v is not None},
            "temperatures": dict(zip(temp.names, temp.values, strict=True)),
        },
    }


def forged_models(genuine: bytes, robot: str) -> list[bytes]:
    """Foreign and forged snapshots: a UR10 model under this robot's name, the genuine snapshot
    with an implausible version, a wrong robot, a nested ``unverified`` or a negative
    ``drift_scale`` of three factors, truncated and random bytes."""
    header, snap = decode_model(genuine)
    ur10 = load_description("ur10")
    foreign = ErrorModel.create(
        feature_spec(ur10, 0, False), ModelConfig(hidden_layers=1, neurons=8), TrainConfig(), 0
    )
    ur10_snap = snapshot_to_bytes(foreign, {"model_version": header.model_version + 1})
    meta = snapshot_meta(snap) | {"unverified": {"nested": [1, {"deeper": None}]}}
    odd_snap = st_save(st_load(snap), metadata={"robocal": json.dumps(meta)})
    bad_drift = st_load(snap) | {"drift_scale": torch.full((3,), -1.0, dtype=torch.float64)}
    drift_snap = st_save(bad_drift, metadata={"robocal": json.dumps(snapshot_meta(snap))})

    def framed(snapshot, version, n_seen, name=robot):
        return encode_model(
            ModelHeader(model_version=version, robot=name, n_seen=n_seen, t=1.0), snapshot
        )

    return [
        framed(ur10_snap, header.model_version + 1, 10_000),
        framed(snap, 10**9, 10**9 + 5),
        framed(snap, 2**53, 2**53),
        framed(snap, header.model_version + 1, 10_000, name="ur10"),
        framed(odd_snap, header.model_version + 1, 10_000),
        framed(drift_snap, header.model_version + 1, 10_000),
        framed(snap[: len(snap) // 2], header.model_version + 1, 10_000),
        framed(b"\x00" * 64, header.model_version + 1, 10_000),
        genuine[:20],
        b"\xff" * 8 + b"{}",
    ]


EXTREME = st.sampled_from(
    [None, True, -1, 2**63, 10**30, 10**9, 1e12, -1e12, 1e308, float("nan"), float("inf"),
     "x", "", [], {}, [1, 2, 3, 4, 5], [[1]], 0.5, "base", "tracker", ["a"], [""]]
)  # fmt: skip
LEAVES = st.none() | st.booleans() | st.integers() | st.floats() | st.text(max_size=6)
JSON = st.recursive(
    LEAVES,
    lambda c: st.lists(c, max_size=4) | st.dictionaries(st.text(max_size=4), c, max_size=3),
    max_leaves=12,
)
FIXED = st.sampled_from(
    [
        b"[" * 100_000 + b"]" * 100_000,  # the RecursionError of the issue
        b'{"a":' * 5_000 + b"1" + b"}" * 5_000,
        b'{"schema":"robocal.joints","version":1,"pad":"' + b"a" * 5_000_000 + b'"}',
        b"",
        b"\x00\xff" * 10,
        b"null",
        b"[]",
        b'"just a string"',
    ]
)


@st.composite
def bad_message(draw, templates, models):
    """``(topic, payload)``: a fixed nasty payload, a template with one field replaced, or
    (on ``model``) a forged snapshot."""
    topic = draw(st.sampled_from(sorted(templates)) | st.just("model"))
    kind = draw(st.sampled_from(["fixed", "mutated", "mutated", "mutated", "model"]))
    if topic == "model" or kind == "model":
        return "model", draw(st.sampled_from(models) | FIXED)
    if kind == "fixed":
        return topic, draw(FIXED)
    template = dict(templates[topic])
    name = draw(st.sampled_from(sorted(template)))
    template[name] = draw(EXTREME | JSON)
    if topic == "batches" and draw(st.booleans()):  # a point inside the batch mutated
        points = template["points"]  # itself replaced above when the draw named it
        first = points[0] if isinstance(points, list) and points else None
        point = dict(first) if isinstance(first, dict) else {}
        point[draw(st.sampled_from(sorted(point) or ["q"]))] = draw(EXTREME | JSON)
        template["points"] = [point]
    return topic, json.dumps(template).encode()


class Later(SimCellSource):
    """The campaign again, ``OFFSET_S`` later (same sequence numbers: the source restarted)."""

    OFFSET_S = 500.0

    def run(self):
        for s in cell_samples(self.ds, self.cfg):
            self.publish(replace(s, t=s.t + self.OFFSET_S))


def publish(run: Live, topic: str, payload: bytes) -> None:
    k = key(CELL, run.robot, topic)
    if k not in run.pubs:
        run.pubs[k] = publisher(run.client, k)
    run.pubs[k].put(payload)


def check_alive(run: Live) -> None:
    for stage in run.daemon.stages:
        stage.drain(10.0)
    failed = run.daemon.failed_stage()
    if failed is not None:
        TALLY["stage_deaths"] += 1
    assert failed is None, f"{failed.name} died: {failed.failure!r}"


@settings(
    max_examples=150,
    deadline=None,
    suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large],
)
@given(data=st.data())
def test_bad_messages_on_every_topic_never_kill_a_stage(live, data):
    topic, payload = data.draw(bad_message(live.templates, live.forged_models))
    TALLY["cases"] += 1
    if topic == "compensate":
        TALLY["queries"] += 1
        replies = list(
            live.client.get(key(CELL, live.robot, "compensate"), payload=payload, timeout=10.0)
        )
        if not replies:
            TALLY["hangs"] += 1
        assert replies, "compensation did not answer"
        r = replies[0]
        if r.ok is not None:
            reply = decode(r.ok.payload.to_bytes(), CompensationReply)
            assert reply.trusted or reply.reason.split(":")[0] in (*CODES, "epistemic")
        else:
            text = r.err.payload.to_bytes().decode()
            assert text and not text.startswith(("invalid", "internal")), text
    else:
        publish(live, topic, payload)
    check_alive(live)


def test_after_the_bad_messages_good_data_is_still_learned(live):
    robot, daemon = live.robot, live.daemon
    n_models, n_points = len(live.models), len(live.points)
    learner = daemon.learners[robot]
    version = learner.core.learner.version
    # the line resumes 500 s later, as after a pause: a jump past every watermark
    later = simulate(get_scenario("paper"), 40, 4)
    Later(live.client, CELL, robot, later, StreamingConfig(period_s=1.0)).start()
    assert wait_for(lambda: learner.core.learner.version >= version + 2, 60.0)
    assert wait_for(lambda: len(live.points) >= n_points + 30, 10.0)
    assert len(live.models) > n_models
    check_alive(live)
    comp = next(s for s in daemon.stages if s.name == "compensation")
    assert wait_for(lambda: comp.version == learner.core.learner.version, 10.0)
    refused = {k: v for k, v in comp.counter.dropped.items() if k.startswith("model_")}
    assert refused.get("model_foreign", 0) + refused.get("model_version", 0) >= 1
    assert set(comp.counter.refused) & {"model_foreign", "model_version"}
    # the window never ran away with a forged time: its watermarks are the genuine stream's
    series = daemon.windows[robot].joiner._series
    assert max(s.high for s in series.values()) < Later.OFFSET_S + 41.0 + 60.0
    mcap = daemon.recordings["mcap"]
    t0 = time.monotonic()
    failures = daemon.stop(timeout_s=7.0)
    stop_s = time.monotonic() - t0
    assert failures == {} and stop_s < 10.0
    with open(mcap, "rb") as f:
        summary = make_reader(f).get_summary()  # footer and summary written
    assert summary is not None and summary.statistics.message_count > 0
    TALLY.update(
        models_refused=sum(refused.get(k, 0) for k in ("model_foreign", "model_version")),
        refused_by_reason=refused,
        stop_s=round(stop_s, 2),
        window_dropped=dict(daemon_window_dropped(live)),
    )
    print("\nfuzz tally:", json.dumps(TALLY, sort_keys=True))


def daemon_window_dropped(live: Live) -> dict:
    d = live.diagnostics.get("window")
    return {} if d is None else dict(sorted(d.dropped.items()))
