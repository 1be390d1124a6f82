"""The deployment files parse: the Zenoh router config and the systemd unit."""

from pathlib import Path

import zenoh

DEPLOY = Path(__file__).resolve().parents[2] / "deploy"


def test_router_config_is_valid_zenoh():
    cfg = zenoh.Config.from_file(str(DEPLOY / "zenohd.json5"))
    assert '"router"' in cfg.get_json("mode")


def test_service_runs_the_daemon_and_stops_it_with_sigterm():
    unit = (DEPLOY / "robocal.service").read_text()
    assert "ExecStart=" in unit and "robocal run --config" in unit
    assert "KillSignal=SIGTERM" in unit
