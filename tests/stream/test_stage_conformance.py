"""One conformance suite for every registered stage (``stream.stages.STAGES``), on real Zenoh
sessions on loopback: the registry names the class, the stage announces itself, counts and
drops garbage on every stream and query it takes without dying, and closes cleanly (final
diagnostics published, liveliness token gone). A stage added to the registry fails here until
``BUILD`` knows how to make one.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from pathlib import Path

import pytest
import zenoh

from kinematics.description import load_description
from kinematics.model import RobotModel
from stream.bus import BusConfig, alive_stages, free_port, liveliness_key, open_session
from stream.compensation import CompensationConfig
from stream.dashboard import Dashboard
from stream.learner_core import LearnerStageConfig
from stream.stages import ROBOT_STAGES, STAGES, Stage, stage_class
from stream.window import WindowConfig
from wire import Diagnostics, decode, key

pytestmark = pytest.mark.integration

CELL, ROBOT = "conf", "r1"
GARBAGE = b"\xff{not json"
DESC = load_description("ur10")

Build = Callable[[zenoh.Session, Path], Stage]
BUILD: dict[str, Build] = {
    "window": lambda s, tmp: stage_class("window")(
        s, CELL, ROBOT, WindowConfig(n_joints=DESC.n_joints), state_path=tmp / "w.json"
    ),
    "learner": lambda s, tmp: stage_class("learner")(
        s, CELL, ROBOT, DESC, LearnerStageConfig(), checkpoint=tmp / "c.safetensors"
    ),
    "compensation": lambda s, tmp: stage_class("compensation")(
        s, CELL, ROBOT, RobotModel(DESC), CompensationConfig()
    ),
    "dashboard": lambda s, tmp: stage_class("dashboard")(
        s, CELL, ROBOT, Dashboard(RobotModel(DESC), recording_id="conf"), RobotModel(DESC)
    ),
    "recorder": lambda s, tmp: stage_class("recorder")(s, CELL, tmp / "rec.mcap", 0.2),
}


@pytest.fixture(scope="module")
def sessions():
    port = free_port()
    a = open_session(BusConfig.loopback(port, listen=True))
    b = open_session(BusConfig.loopback(port, listen=False))
    time.sleep(0.5)  # let the client connect before anything is declared
    yield a, b
    b.close()
    a.close()


def _wait(cond: Callable[[], bool], timeout_s: float = 30.0) -> bool:
    deadline = time.monotonic() + timeout_s
    while not cond():
        if time.monotonic() > deadline:
            return False
        time.sleep(0.05)
    return True


def test_every_registered_stage_has_a_builder_and_its_name():
    assert set(BUILD) == set(STAGES)
    assert tuple(n for n in STAGES if n != "recorder") == ROBOT_STAGES
    for name in STAGES:
        cls = stage_class(name)
        assert issubclass(cls, Stage) and cls.name == name


def test_unknown_stage_names_the_known_ones():
    from kinematics.errors import ConfigError

    with pytest.raises(ConfigError, match="unknown stage 'windows'; known: window, learner"):
        stage_class("windows")


@pytest.mark.parametrize("name", list(STAGES))
def test_stage_takes_garbage_and_closes_cleanly(name, sessions, tmp_path):
    a, b = sessions
    stage = BUILD[name](a, tmp_path)
    robot = stage.robot
    try:
        alive = liveliness_key(CELL, robot, name)
        assert _wait(lambda: alive in alive_stages(b, CELL)), f"{alive} never announced"
        diags: list[Diagnostics] = []
        b_sub = b.declare_subscriber(
            key(CELL, robot, "diagnostics"),
            lambda s: diags.append(decode(s.payload.to_bytes(), Diagnostics)),
        )
        streams = [str(s.key_expr) for s in stage._subs if "*" not in str(s.key_expr)]
        if not streams:  # a wildcard subscriber (the recorder) takes any stream of the cell
            streams = [key(CELL, "r9", "joints")]
        for k in streams:  # each put once the stage's subscriber is known, or it may be lost
            pub = b.declare_publisher(k)
            assert _wait(lambda pub=pub: pub.matching_status.matching), f"no subscriber on {k}"
            pub.put(GARBAGE)
            pub.undeclare()

        def accounted() -> int:
            stage.count_worker_drops()
            return stage.counter.accepted + sum(stage.counter.dropped.values())

        assert _wait(lambda: accounted() >= len(streams)), stage.counter.diagnostics()
        if name != "recorder":  # every stream but the recorder's raw log rejects garbage
            assert sum(stage.counter.dropped.values()) >= len(streams)
        for q, _ in stage._queryables:  # a bad query is answered (or not), never fatal
            replies = list(b.get(str(q.key_expr), payload=GARBAGE, timeout=10.0))
            errors = [r.err.payload.to_string() for r in replies if r.err is not None]
            assert all(e and "\n" not in e for e in errors), errors
        assert stage.failure is None
    finally:
        assert stage.close(timeout_s=30.0) is None
    assert _wait(lambda: any(d.stage == name for d in diags)), "no final diagnostics"
    b_sub.undeclare()
    assert _wait(lambda: alive not in alive_stages(b, CELL)), f"{alive} still announced"
