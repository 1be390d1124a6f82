"""Two workers share one study on a real PostgreSQL server (Debian's ``postgresql`` package).

The server runs on loopback in a temporary data directory (as the ``postgres`` user when the
tests run as root: PostgreSQL refuses root) and is stopped afterwards. Skips, with the reason,
where the server binaries or the Python driver are absent.
"""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
import tempfile
import time
from collections.abc import Iterator
from pathlib import Path

import optuna
import pytest
from optuna.trial import TrialState

from kinematics.dataset import write_dataset
from learner.hpo_study import WORKER_ATTR, open_storage
from stream.bus import free_port
from tests.learner.test_hpo import TINY_TOML, toy_dataset

pytestmark = pytest.mark.integration


def _pg_bin() -> Path | None:
    found = sorted(Path("/usr/lib/postgresql").glob("*/bin/pg_ctl"))
    if found:
        return found[-1].parent
    on_path = shutil.which("pg_ctl")
    return Path(on_path).parent if on_path else None


@pytest.fixture(scope="module")
def postgres_url() -> Iterator[str]:
    """A throw-away PostgreSQL server on 127.0.0.1; its SQLAlchemy URL."""
    bindir = _pg_bin()
    if bindir is None:
        pytest.skip(
            "PostgreSQL server binaries (initdb, pg_ctl) not found: apt-get install postgresql"
        )
    pytest.importorskip("psycopg2", reason="psycopg2 driver not installed: pip install -e '.[dev]'")
    as_user: list[str] = []
    if os.geteuid() == 0:
        if shutil.which("runuser") is None:
            pytest.skip("running as root without runuser: cannot start PostgreSQL as another user")
        as_user = ["runuser", "-u", "postgres", "--"]
    root = Path(tempfile.mkdtemp(prefix="robocal-pg-"))
    data = root / "data"
    if as_user:
        shutil.chown(root, "postgres")
    port = free_port()
    subprocess.run(
        [*as_user, str(bindir / "initdb"), "-D", str(data), "-U", "postgres", "--auth=trust"],
        check=True,
        capture_output=True,
    )
    opts = f"-p {port} -k {root} -c listen_addresses=127.0.0.1 -c fsync=off"
    log = str(root / "log")
    subprocess.run(
        [*as_user, str(bindir / "pg_ctl"), "-D", str(data), "-o", opts, "-l", log, "-w", "start"],
        check=True,
        capture_output=True,
    )
    try:
        yield f"postgresql+psycopg2://postgres@127.0.0.1:{port}/postgres"
    finally:
        subprocess.run(
            [*as_user, str(bindir / "pg_ctl"), "-D", str(data), "-m", "immediate", "stop"],
            capture_output=True,
        )
        shutil.rmtree(root, ignore_errors=True)


def _hpo(data: Path, storage: str, out: Path, space: Path, *extra: str) -> subprocess.Popen:
    robocal = Path(sys.executable).parent / "robocal"
    cmd = [
        str(robocal), "hpo", "--data", str(data), "--trials", "6", "--threads", "1",
        "--storage", storage, "--study", "pg", "--base", "nominal", "--space", str(space),
        "--folds", "2", "--epochs", "80", "--no-prune", "--json", "--out", str(out), *extra,
    ]  # fmt: skip
    return subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)


def _finish(workers: list[subprocess.Popen]) -> list[dict]:
    deadline = time.monotonic() + 300
    outputs = [w.communicate(timeout=max(1, deadline - time.monotonic())) for w in workers]
    assert [w.returncode for w in workers] == [0] * len(workers), [o[1][-800:] for o in outputs]
    return [json.loads(o[0]) for o in outputs]


def test_two_workers_share_one_postgres_study(postgres_url, tmp_path):
    data = write_dataset(toy_dataset(60), tmp_path / "d.parquet")
    (tmp_path / "space.toml").write_text(TINY_TOML)
    workers = [
        _hpo(data, postgres_url, tmp_path / f"m{k}.safetensors", tmp_path / "space.toml")
        for k in range(2)
    ]
    reports = _finish(workers)
    assert sum(r["ran_here"] for r in reports) == 6 and min(r["ran_here"] for r in reports) >= 1
    study = optuna.load_study(study_name="pg", storage=open_storage(postgres_url))
    assert len(study.trials) == 6  # exactly --trials: the advisory lock serialises count-and-ask
    assert all(t.state == TrialState.COMPLETE for t in study.trials)
    by_worker = {t.user_attrs[WORKER_ATTR] for t in study.trials}
    assert {str(w.pid) for w in workers} == {b.rpartition(":")[2] for b in by_worker}


def test_workers_option_runs_helper_processes_on_one_journal(tmp_path):
    data = write_dataset(toy_dataset(60), tmp_path / "d.parquet")
    (tmp_path / "space.toml").write_text(TINY_TOML)
    journal = str(tmp_path / "s.journal")
    out = tmp_path / "m.safetensors"
    (report,) = _finish([_hpo(data, journal, out, tmp_path / "space.toml", "--workers", "2")])
    assert report["workers"] == 2 and report["worker_exit_codes"] == [0]
    study = optuna.load_study(study_name="pg", storage=open_storage(journal))
    assert len(study.trials) == 6 and report["complete"] == 6
    assert len({t.user_attrs[WORKER_ATTR] for t in study.trials}) in (1, 2)  # helper may be late


def test_unreachable_postgres_exits_2(tmp_path, capsys):
    from stream.cli import main

    data = write_dataset(toy_dataset(20), tmp_path / "d.parquet")
    url = f"postgresql+psycopg2://nobody@127.0.0.1:{free_port()}/none"
    pytest.importorskip("psycopg2", reason="psycopg2 driver not installed")
    assert main(["hpo", "--data", str(data), "--storage", url, "--base", "nominal"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "cannot open" in err[0], err
