"""A two-robot line on loopback: the shipped router config (mutual TLS, access control), a
``robocal run`` daemon for both robots (learner certificate), a dashboard daemon (dashboard
certificate), and sources publishing with the robot, tracker and DAQ certificates; models
come out for each robot and a compensation client gets answers. A robot that cannot start
stops the daemon with exit code 2 and one line."""

import io
import json
import signal
import socket
import subprocess
import sys
import threading
import time
import tomllib
import urllib.request
from pathlib import Path

import pytest
import zenoh

from kinematics.errors import ConfigError, RobocalError
from sim_sources.cell import simulate
from sim_sources.scenarios import get_scenario
from sim_sources.streaming import StreamingConfig, cell_samples
from stream.bus import BusConfig, TlsConfig, alive_stages, free_port, open_session
from stream.compensation import CompensationReply, CompensationRequest
from stream.config import config_from_dict, load_config
from stream.config_render import loopback_config, write_config
from stream.daemon import Daemon
from stream.log import JsonLogger
from stream.router import open_router, router_config
from stream.security import ROLES, make_line_certs
from wire import JointSample, TemperatureSample, TrackerSample, decode, encode, key

pytestmark = pytest.mark.integration
DEPLOY = Path(__file__).resolve().parents[2] / "deploy"
ROBOCAL = str(Path(sys.executable).with_name("robocal"))
ROBOTS = ("r1", "r2")
LEARNER = """
[window]
batch_size = 10

[learner]
holdout_every = 5

[learner.model]
hidden_layers = 1
neurons = 8
members = 1

[learner.continual]
memory = 30
batch = 10
init = 10
epochs_per_update = 3
init_epochs = 10
"""


def line_toml(certs: Path, role: str, port: int, stages: list[str], extra: str = "") -> str:
    """A line config: both robots in one file, a client of the router with ``role``'s cert."""
    tls = {k: str(certs / f) for k, f in (("ca", "ca.pem"), ("cert", f"{role}.pem"))}
    tls["key"] = str(certs / f"{role}.key")
    robots = "".join(
        f'[[robot]]\nname = "{r}"\ndescription = "fanuc_m900ib700"\nstages = {json.dumps(stages)}\n'
        f"T_W_0 = {{T_W_0}}\n\n"
        for r in ROBOTS
    )
    tls_line = ", ".join(f'{k} = "{v}"' for k, v in tls.items())
    return (
        f'cell = "line"\n{extra}\n[bus]\nmode = "client"\n'
        f'connect = ["tls/127.0.0.1:{port}"]\nmulticast_scouting = false\n'
        f"tls = {{ {tls_line} }}\n\n{robots}{LEARNER}"
    )


def role_session(certs: Path, role: str, port: int) -> zenoh.Session:
    tls = TlsConfig(
        ca=str(certs / "ca.pem"), cert=str(certs / f"{role}.pem"), key=str(certs / f"{role}.key")
    )
    return open_session(BusConfig.loopback(port, listen=False, tls=tls))


def publish_sources(sessions: dict[str, zenoh.Session], robot: str, ds) -> int:
    """The cell's samples, each stream from the session of its role (robot, tracker, DAQ)."""
    streams = {JointSample: ("robot", "joints"), TrackerSample: ("tracker", "tracker")}
    streams[TemperatureSample] = ("daq", "temperature")
    pubs, n = {}, 0
    for sample in cell_samples(ds, StreamingConfig(period_s=1.0)):
        role, stream = streams[type(sample)]
        if stream not in pubs:
            pubs[stream] = sessions[role].declare_publisher(
                key("line", robot, stream), congestion_control=zenoh.CongestionControl.BLOCK
            )
        pubs[stream].put(encode(sample))
        n += 1
    for p in pubs.values():
        p.undeclare()
    return n


def test_two_robot_line_end_to_end_over_tls(tmp_path):
    certs = tmp_path / "certs"
    make_line_certs(certs, ROLES)
    port = free_port()
    router = open_router(router_config(DEPLOY / "zenohd.json5", (f"tls/127.0.0.1:{port}",), certs))
    data = {r: simulate(get_scenario("paper"), 30, seed) for seed, r in enumerate(ROBOTS)}
    T_W_0 = json.dumps(data["r1"].meta.T_W_0)
    (tmp_path / "state").mkdir()
    learner_cfg = tmp_path / "line.toml"
    learner_cfg.write_text(
        line_toml(
            certs,
            "learner",
            port,
            ["window", "learner", "compensation"],
            f'checkpoint_dir = "{tmp_path / "state"}"',
        ).replace("{T_W_0}", T_W_0)
    )
    proc = subprocess.Popen(
        [ROBOCAL, "run", "--config", str(learner_cfg)], stderr=subprocess.PIPE, text=True
    )
    sessions = {
        r: role_session(certs, r, port) for r in ("robot", "tracker", "daq", "compensation")
    }
    dash_text = line_toml(certs, "dashboard", port, ["dashboard"]).replace("{T_W_0}", T_W_0)
    dash_text += f'\n[dashboard]\nrrd = "{tmp_path / "line.rrd"}"\n'
    (tmp_path / "dashboard.toml").write_text(dash_text)
    dashboard = Daemon(load_config(tmp_path / "dashboard.toml")).start()
    try:
        client = sessions["compensation"]
        deadline = time.monotonic() + 90
        while len(alive_stages(client, "line", timeout_s=0.5)) < 8:  # 3 + 1 stages per robot
            assert proc.poll() is None, proc.stderr.read()
            assert time.monotonic() < deadline, alive_stages(client, "line")
            time.sleep(0.2)
        models = {r: [] for r in ROBOTS}
        subs = [
            client.declare_subscriber(key("line", r, "model"), lambda s, r=r: models[r].append(1))
            for r in ROBOTS
        ]
        time.sleep(0.3)
        for r in ROBOTS:
            assert publish_sources(sessions, r, data[r]) > 0
        deadline = time.monotonic() + 60
        while not all(models.values()) and time.monotonic() < deadline:
            assert proc.poll() is None, proc.stderr.read()
            time.sleep(0.1)
        assert all(models.values()), models
        for r in ROBOTS:  # a compensation client of the line gets each robot's answer
            ds = data[r]
            temps = {c[5:]: float(ds.table[c].iloc[0]) for c in ds.table if c.startswith("temp_")}
            req = CompensationRequest(
                q=tuple(ds.q()[0]), temperatures=temps, deflection=tuple(ds.deflection()[0])
            )
            replies = ask_until_adopted(client, key("line", r, "compensate"), encode(req))
            assert len(replies) == 1
            assert replies[0].ok is not None, replies[0].err.payload.to_string()
            reply = decode(replies[0].ok.payload.to_bytes(), CompensationReply)
            assert reply.model_version >= 0 and len(reply.q_corrected) == 6
        for sub in subs:
            sub.undeclare()
        proc.send_signal(signal.SIGTERM)
        assert proc.wait(60) == 0
        for r in ROBOTS:  # each robot's own state, side by side in one directory
            assert (tmp_path / "state" / f"{r}.checkpoint.safetensors").exists()
        seen = {st.robot: st.counter.accepted for st in dashboard.stages}
        assert set(seen) == set(ROBOTS) and all(seen.values()), seen
    finally:
        if proc.poll() is None:
            proc.kill()
        dashboard.stop(timeout_s=10)
        for s in sessions.values():
            s.close()
        router.close()
    for r in ROBOTS:
        assert (tmp_path / f"line_{r}.rrd").stat().st_size > 0


def ask_until_adopted(client, topic: str, payload: bytes, timeout_s: float = 30.0) -> list:
    """The replies to a compensate query, asked again while the service answers ``no_model``:
    it adopts a model on its own worker (decoded, checked) some time after the model is on
    the bus, where a test's subscriber may already have seen it."""
    deadline = time.monotonic() + timeout_s
    while True:
        replies = list(client.get(topic, payload=payload, timeout=10.0))
        waiting = [r for r in replies if r.ok is None and b"no_model" in r.err.payload.to_bytes()]
        if not waiting or time.monotonic() > deadline:
            return replies
        time.sleep(0.2)


def two_robots(tmp_path: Path, r2_description: str) -> dict:
    """A loopback config of robots r1 (the Fanuc) and r2 (``r2_description``), state in tmp."""
    r1 = {"name": "r1", "description": "fanuc_m900ib700"}
    r2 = {"name": "r2", "description": r2_description}
    return loopback_config("line", free_port(), r1, r2, checkpoint_dir=str(tmp_path))


def test_a_robot_that_cannot_start_stops_the_daemon_with_exit_2_and_one_line(tmp_path):
    """The second robot's checkpoint is corrupt, found after the first robot's stages are
    open: they close again, the bus closes, one line, exit 2, no hang."""
    (tmp_path / "r2.checkpoint.safetensors").write_bytes(b"not a checkpoint")
    cfg = write_config(tmp_path / "line.toml", two_robots(tmp_path, "fanuc_m900ib700"))
    proc = subprocess.Popen(
        [ROBOCAL, "run", "--config", str(cfg)], stderr=subprocess.PIPE, text=True
    )
    try:
        _, err = proc.communicate(timeout=120)
    finally:
        proc.kill()
    assert proc.returncode == 2, err
    errors = [line for line in err.splitlines() if not line.startswith("{")]
    assert len(errors) == 1 and errors[0].startswith("robocal: error:"), err
    assert "r2.checkpoint.safetensors" in errors[0]
    assert not any('"level":"error"' in line for line in err.splitlines()), err


def test_a_missing_description_is_refused_before_anything_opens(tmp_path):
    daemon = Daemon(config_from_dict(two_robots(tmp_path, str(tmp_path / "no.toml"))))
    with pytest.raises(RobocalError, match="no.toml"):
        daemon.start()
    assert daemon.session is None and daemon.stages == []


def _free_pair() -> int:
    """A port p with p and p + 1 free on 127.0.0.1 right now."""
    for _ in range(100):
        p = free_port()
        with socket.socket() as s:
            try:
                s.bind(("127.0.0.1", p + 1))
                return p
            except OSError:
                continue
    raise RuntimeError("no two adjacent free ports")


def test_robots_serving_dashboards_get_their_own_ports():
    web, grpc = _free_pair(), _free_pair()
    base = {
        "cell": "c",
        "bus": {"listen": [f"tcp/127.0.0.1:{free_port()}"], "multicast_scouting": False},
        "robot": [{"name": r, "description": "ur10", "stages": ["dashboard"]} for r in ("a", "b")],
        "dashboard": {"serve": True, "web_port": web, "grpc_port": grpc},
    }
    log = io.StringIO()
    daemon = Daemon(config_from_dict(base), logger=JsonLogger(stream=log)).start()
    try:  # both viewers up: before, the second robot's server found the port taken
        for port in (web, web + 1):
            assert urllib.request.urlopen(f"http://127.0.0.1:{port}/", timeout=10).status == 200
    finally:
        daemon.stop(timeout_s=10)
    urls = [json.loads(x)["url"] for x in log.getvalue().splitlines() if "dashboard_served" in x]
    assert len(urls) == 2 and f"%3A{grpc + 1}%2F" in urls[1]
    with pytest.raises(ConfigError, match="overlap"):
        config_from_dict(
            {**base, "dashboard": {"serve": True, "web_port": 9090, "grpc_port": 9091}}
        )


def test_a_daemon_waits_for_a_router_that_starts_later_or_for_its_stop(tmp_path):
    certs = tmp_path / "certs"
    make_line_certs(certs, ("router", "learner", "tracker"))
    port = free_port()

    def config(role: str):
        text = line_toml(certs, role, port, ["window"]).replace("{T_W_0}", "[]")
        return config_from_dict(tomllib.loads(text.replace("T_W_0 = []\n", "")))

    cfg = config("learner")
    log = io.StringIO()
    daemon, until = Daemon(cfg, logger=JsonLogger(stream=log)), threading.Event()
    starting = threading.Thread(target=daemon.start, kwargs={"until": until})
    starting.start()
    deadline = time.monotonic() + 30
    while "bus_unreachable" not in log.getvalue():
        assert time.monotonic() < deadline and starting.is_alive()
        time.sleep(0.1)
    router = open_router(router_config(DEPLOY / "zenohd.json5", (f"tls/127.0.0.1:{port}",), certs))
    try:
        starting.join(60)
        assert not starting.is_alive() and [st.name for st in daemon.stages] == ["window"] * 2
        assert "bus_role" not in log.getvalue()
        wrong_log = io.StringIO()  # a window stage under the tracker's certificate: warned
        Daemon(config("tracker"), logger=JsonLogger(stream=wrong_log)).start().stop(10)
        assert '"event":"bus_role","certificate":"tracker"' in wrong_log.getvalue()
    finally:
        daemon.stop(timeout_s=10)
        router.close()
    idle = Daemon(cfg, logger=JsonLogger(stream=io.StringIO()))  # no router, then SIGTERM
    stop = threading.Event()
    threading.Timer(1.0, stop.set).start()
    assert idle.start(until=stop).session is None and idle.stages == []
