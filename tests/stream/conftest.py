"""Fixtures shared by the stream tests."""

from __future__ import annotations

import subprocess
import sys
import time
import tomllib
from collections.abc import Callable
from pathlib import Path

import numpy as np
import pytest
import torch

from kinematics.description import load_description
from kinematics.model import RobotModel
from learner.config import ModelConfig, TrainConfig
from learner.features import feature_spec
from learner.model import ErrorModel
from stream.bus import alive_stages, wait_matched
from stream.config_render import loopback_config, write_config

Labels = Callable[[np.ndarray], np.ndarray]


@pytest.fixture(scope="session")
def train_fanuc() -> Callable[[int, ModelConfig, int, Labels], tuple]:
    """A factory: the Fanuc M-900iB/700 and an :class:`ErrorModel` (seed 0, features: joints
    and one ambient temperature at 20 °C) trained for ``max_epochs`` on ``n`` seeded poses in
    half the joint range against ``labels(q)`` (m, rad); returns ``(robot, model, q)``."""

    def train(n: int, model_cfg: ModelConfig, max_epochs: int, labels: Labels) -> tuple:
        torch.set_num_threads(1)
        robot = RobotModel(load_description("fanuc_m900ib700"))
        spec = feature_spec(robot.description, 1, False, ("ambient",))
        rng = np.random.default_rng(0)
        lim = robot.description.limits_rad * 0.5
        q = rng.uniform(lim[:, 0], lim[:, 1], size=(n, 6))
        X = np.hstack([q, np.full((n, 1), 20.0)])
        model = ErrorModel.create(spec, model_cfg, TrainConfig(max_epochs=max_epochs), seed=0)
        model.fit(X, labels(q))
        return robot, model, q

    return train


def daemon_config(
    path: Path,
    *,
    port: int,
    T_W_0: list[list[float]],
    state: Path,
    robot: str = "fanuc_m900ib700",
    recorder: Path | None = None,
    settings: str = "",
    batch_size: int = 10,
    neurons: int = 8,
    **continual: int | str,
) -> Path:
    """Write a ``robocal run`` config to ``path``: cell "plant", one robot's window and learner
    on loopback ``port`` (checkpoints in ``state``; top-level ``settings`` TOML lines; an MCAP
    recorder at ``recorder`` when given; ``[learner.continual]`` memory 30, batch 10, init 10,
    3 epochs per update and 10 initial unless overridden)."""
    cont = {"memory": 30, "batch": 10, "init": 10, "epochs_per_update": 3, "init_epochs": 10}
    robot_table = {
        "name": robot,
        "description": robot,
        "stages": ["window", "learner"],
        "T_W_0": np.asarray(T_W_0, dtype=float).tolist(),
    }
    raw = loopback_config(
        "plant",
        port,
        robot_table,
        checkpoint_dir=str(state),
        **tomllib.loads(settings),
        window={"batch_size": batch_size},
        learner={
            "holdout_every": 5,
            "model": {"hidden_layers": 1, "neurons": neurons},
            "continual": cont | continual,
        },
    )
    if recorder is not None:
        raw["recorder"] = {"path": str(recorder), "flush_interval_s": 0.2}
    return write_config(path, raw)


def start_daemon(config: Path) -> subprocess.Popen:
    """``robocal run --config config`` as a real process (stderr, the JSON log, piped)."""
    exe = str(Path(sys.executable).with_name("robocal"))
    return subprocess.Popen(
        [exe, "run", "--config", str(config)], stderr=subprocess.PIPE, text=True
    )


def wait_for(cond: Callable[[], bool], timeout: float = 60.0) -> bool:
    """Poll ``cond`` every 50 ms until it holds or ``timeout`` (s) passes; its last value."""
    deadline = time.monotonic() + timeout
    while not cond() and time.monotonic() < deadline:
        time.sleep(0.05)
    return cond()


def wait_subscribed(session, *keyexprs: str, timeout: float = 60.0) -> None:
    """Wait until ``session`` knows a subscriber on each of ``keyexprs``: a put before that is
    lost (a fixed pause before the first put was too short on a loaded 2-core machine)."""
    pubs = [session.declare_publisher(keyexpr) for keyexpr in keyexprs]
    try:
        waiting = wait_matched(pubs, timeout)
        assert not waiting, f"no subscriber on {waiting}"
    finally:
        for pub in pubs:
            pub.undeclare()


def wait_alive(session, n: int, proc: subprocess.Popen, timeout: float = 60.0) -> None:
    """Wait until ``n`` stages of cell "plant" are alive; fail at once if ``proc`` exits."""
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        assert proc.poll() is None, proc.stderr.read()
        if len(alive_stages(session, "plant", timeout_s=0.5)) >= n:
            return
        time.sleep(0.1)
    raise AssertionError("stages did not come alive")


def kill_running(*procs: subprocess.Popen | None) -> None:
    """Kill each of ``procs`` that is still running (a test's clean-up; None is skipped)."""
    for p in procs:
        if p is not None and p.poll() is None:
            p.kill()


@pytest.fixture
def small_fs(tmp_path):
    """A 2 MB tmpfs at ``tmp_path/state`` (unmounted afterwards)."""
    mnt = tmp_path / "state"
    mnt.mkdir()
    done = subprocess.run(
        ["mount", "-t", "tmpfs", "-o", "size=2m", "tmpfs", str(mnt)], capture_output=True
    )
    if done.returncode != 0:
        pytest.skip(f"cannot mount a tmpfs (needs root): {done.stderr.decode().strip()}")
    yield mnt
    subprocess.run(["umount", "-l", str(mnt)], check=False)


def fill(directory: Path) -> Path:
    """Fill the file system of ``directory`` to the last byte; the filler file."""
    filler = directory / "filler"
    with filler.open("wb", buffering=0) as f:  # unbuffered: closing never writes more
        try:
            while True:
                f.write(b"\0" * 4096)
        except OSError:
            pass
    return filler
