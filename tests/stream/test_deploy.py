"""The deployment files: the Zenoh router config (TLS, access control) runs under
``robocal router``, the systemd units are hardened and stop restarting on exit code 2, the
sysusers entry makes the ``robocal`` user, and the example configs load."""

import json
import shutil
import signal
import subprocess
import sys
from pathlib import Path

import pytest
import zenoh

from stream.bus import BusConfig, TlsConfig, free_port, open_session
from stream.cli import main
from stream.config import load_config
from stream.security import make_line_certs

DEPLOY = Path(__file__).resolve().parents[2] / "deploy"
UNITS = sorted(DEPLOY.glob("*.service"))
MAX_EXPOSURE = 4.9  # systemd-analyze security: "OK" and better


def test_router_config_is_valid_zenoh_with_tls_and_access_control():
    cfg = zenoh.Config.from_file(str(DEPLOY / "zenohd.json5"))
    assert json.loads(cfg.get_json("mode")) == "router"
    assert all(e.startswith("tls/") for e in json.loads(cfg.get_json("listen/endpoints")))
    assert json.loads(cfg.get_json("transport/link/tls/enable_mtls")) is True
    acl = json.loads(cfg.get_json("access_control"))
    assert acl["enabled"] and acl["default_permission"] == "deny"


def test_units_run_robocal_and_do_not_restart_on_exit_2():
    assert {u.name for u in UNITS} == {"robocal.service", "robocal-router.service"}
    for unit in UNITS:
        text = unit.read_text()
        assert "ExecStart=/opt/robocal/.venv/bin/robocal " in text
        assert "KillSignal=SIGTERM" in text and "Restart=on-failure" in text
        assert "RestartPreventExitStatus=2" in text and "EnvironmentFile=" in text
        assert "User=robocal" in text
    assert "robocal run --config" in (DEPLOY / "robocal.service").read_text()
    assert "robocal router --config" in (DEPLOY / "robocal-router.service").read_text()


@pytest.mark.skipif(not shutil.which("systemd-analyze"), reason="systemd-analyze not installed")
@pytest.mark.parametrize("unit", UNITS, ids=lambda u: u.name)
def test_units_are_hardened(unit):
    out = subprocess.run(
        ["systemd-analyze", "security", "--offline=true", "--no-pager", str(unit)],
        capture_output=True,
        text=True,
        timeout=60,
    )
    last = [line for line in out.stdout.splitlines() if "Overall exposure level" in line]
    assert last, out.stdout + out.stderr
    exposure = float(last[0].split(":")[1].split()[0])
    assert exposure <= MAX_EXPOSURE, last[0]


@pytest.mark.skipif(not shutil.which("systemd-sysusers"), reason="systemd-sysusers not installed")
def test_sysusers_entry_makes_the_robocal_user(tmp_path):
    (tmp_path / "etc").mkdir()
    conf = DEPLOY / "robocal.sysusers.conf"
    subprocess.run(["systemd-sysusers", f"--root={tmp_path}", str(conf)], check=True, timeout=60)
    user = [
        x
        for x in (tmp_path / "etc" / "passwd").read_text().splitlines()
        if x.startswith("robocal:")
    ]
    assert user and user[0].endswith(":/var/lib/robocal:/usr/sbin/nologin")


def test_example_configs_load():
    single, line = (
        load_config(DEPLOY / "robocal.example.toml"),
        load_config(DEPLOY / "line.example.toml"),
    )
    assert single.bus.tls is not None and line.bus.tls is not None
    assert len(line.robots) >= 2 and line.checkpoint_dir == single.checkpoint_dir


@pytest.mark.integration
def test_robocal_router_serves_the_shipped_config_until_sigterm(tmp_path):
    certs = make_line_certs(tmp_path, ("router", "learner"))
    port = free_port()
    robocal = str(Path(sys.executable).with_name("robocal"))
    args = ["router", "--config", str(DEPLOY / "zenohd.json5"), "--certs", str(tmp_path)]
    proc = subprocess.Popen(
        [robocal, *args, "--listen", f"tls/127.0.0.1:{port}"], stderr=subprocess.PIPE, text=True
    )
    try:
        assert "router_started" in proc.stderr.readline()
        cert, key = certs.roles["learner"]
        tls = TlsConfig(ca=str(certs.ca), cert=str(cert), key=str(key))
        open_session(BusConfig.loopback(port, listen=False, tls=tls)).close()
        proc.send_signal(signal.SIGTERM)
        assert proc.wait(30) == 0
    finally:
        proc.kill()


# SIGTERM is process-directed: Linux may hand it to any thread, one of zenoh's among them.
# Python then runs the handler only when the main thread next runs bytecode; a main thread
# blocked in one untimed wait never does (CI saw the router hang 30 s this way).
SIGNAL_ON_ANOTHER_THREAD = """
import signal, sys, threading, time
from stream.router import router_config, run_router

def kill_from_a_helper_thread(endpoints):
    def send():
        time.sleep(0.3)
        signal.pthread_kill(threading.get_ident(), signal.SIGTERM)
    threading.Thread(target=send, daemon=True).start()

zc = router_config(sys.argv[1], ("tls/127.0.0.1:" + sys.argv[2],), sys.argv[3])
sys.exit(run_router(zc, kill_from_a_helper_thread))
"""


@pytest.mark.integration
def test_robocal_router_stops_when_sigterm_lands_on_another_thread(tmp_path):
    make_line_certs(tmp_path, ("router",))
    config, port = str(DEPLOY / "zenohd.json5"), str(free_port())
    args = [sys.executable, "-c", SIGNAL_ON_ANOTHER_THREAD, config, port, str(tmp_path)]
    assert subprocess.run(args, cwd=DEPLOY.parent, timeout=30).returncode == 0


def test_robocal_router_refuses_unreadable_certificates_in_one_line(tmp_path, capsys):
    args = ["router", "--config", str(DEPLOY / "zenohd.json5"), "--certs", str(tmp_path)]
    assert main(args) == 2
    err = capsys.readouterr().err.splitlines()
    assert len(err) == 1 and "cannot be read" in err[0]
