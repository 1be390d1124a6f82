"""``robocal hpo --dashboard``: optuna-dashboard from an optional extra, or one clear line."""

from __future__ import annotations

import sys
import time
import urllib.request

import pytest

from kinematics.dataset import write_dataset
from kinematics.errors import ConfigError
from learner.hpo_dashboard import start_dashboard
from stream.bus import free_port
from stream.cli import main
from tests.learner.test_hpo import toy_dataset


def test_missing_dashboard_is_one_line_exit_2(tmp_path, monkeypatch, capsys):
    monkeypatch.setitem(sys.modules, "optuna_dashboard", None)  # import fails as if absent
    data = write_dataset(toy_dataset(20), tmp_path / "d.parquet")
    code = main(["hpo", "--data", str(data), "--dashboard", "--storage", str(tmp_path / "s.j")])
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 2 and len(err) == 1
    assert "--dashboard needs optuna-dashboard: pip install -e '.[dashboard]'" in err[0]
    with pytest.raises(ConfigError, match="optuna-dashboard"):
        start_dashboard(tmp_path / "s.j")


def test_dashboard_serves_the_study(tmp_path):
    pytest.importorskip("optuna_dashboard", reason="optional extra not installed")
    url = start_dashboard(tmp_path / "s.journal", port=free_port())
    deadline = time.monotonic() + 30
    while True:
        try:
            with urllib.request.urlopen(url + "api/studies", timeout=2) as r:
                assert r.status == 200 and r.read().startswith(b"{")
            break
        except OSError:
            if time.monotonic() > deadline:
                raise
            time.sleep(0.2)
