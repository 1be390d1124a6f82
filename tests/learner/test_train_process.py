"""A child process trains the same weights as the caller's own process, and a lost or failed
child costs no update (real child interpreters, real small models)."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

import numpy as np
import pytest
import torch

from kinematics.description import load_description
from learner.config import ModelConfig, TrainConfig
from learner.features import feature_spec
from learner.model import ErrorModel
from learner.train_process import TrainProcess

SPEC = feature_spec(load_description("ur10"), 0, False)
MODEL = ModelConfig(hidden_layers=2, neurons=16)


def _points(n: int, seed: int) -> tuple[np.ndarray, np.ndarray]:
    rng = np.random.default_rng(seed)
    X = rng.uniform(-2.0, 2.0, (n, 6))
    Y = 1e-3 * np.c_[np.sin(X[:, :3]) + 0.05 * rng.standard_normal((n, 3)), 0.1 * np.cos(X[:, 3:])]
    return X, Y


def _model() -> ErrorModel:
    return ErrorModel.create(SPEC, MODEL, TrainConfig(batch_size=32, early_stop_patience=5), 0)


def _same_weights(a: ErrorModel, b: ErrorModel) -> bool:
    pairs = zip(a.net.state_dict().values(), b.net.state_dict().values(), strict=True)
    return all(torch.equal(x, y) for x, y in pairs)


@pytest.fixture(scope="module")
def trainer():
    trainer = TrainProcess()
    yield trainer
    trainer.close()


def test_the_child_trains_the_weights_the_caller_would(trainer):
    """Warm-started three times, with a validation split (early stopping, best epoch kept), with
    a given validation set and annealed (a continual update): bit for bit the same weights,
    reports and calibration."""
    X, Y = _points(300, 0)
    here, there = _model(), _model()
    given = dict(X_val=X[:40], Y_val=Y[:40], max_epochs=15, lr=3e-4)
    reports = []
    for fit in (dict(max_epochs=40), given, given | {"anneal": True}):
        a = here.fit(X[40:], Y[40:], **fit)
        reports.append(a)
        b = there.fit(X[40:], Y[40:], **fit, trainer=trainer)
        assert _same_weights(here, there)
        assert (a.epochs, a.best_epoch, a.best_val_mse, a.val_mse_history) == (
            b.epochs,
            b.best_epoch,
            b.best_val_mse,
            b.val_mse_history,
        )
        np.testing.assert_array_equal(here.interval_scale, there.interval_scale)
    assert reports[1].best_epoch < reports[1].epochs  # the validation path was taken
    assert a.final_lr == pytest.approx(0.0, abs=1e-12)  # the annealed fit ran as annealed
    assert trainer.trained == 3 and trainer.failures == 0


def test_a_child_killed_between_or_during_updates_costs_no_update():
    """Killed between two updates: a new child trains the next. Killed during one (a timer on
    another thread): that update trains in this process. Each is reported once."""
    reasons: list[str] = []
    trainer = TrainProcess(on_failure=reasons.append)
    try:
        X, Y = _points(200, 1)
        here, there = _model(), _model()
        here.fit(X, Y, max_epochs=10)
        there.fit(X, Y, max_epochs=10, trainer=trainer)
        first = trainer.pid
        os.kill(first, signal.SIGKILL)
        here.fit(X, Y, max_epochs=10)
        there.fit(X, Y, max_epochs=10, trainer=trainer)
        assert _same_weights(here, there) and trainer.pid != first
        assert trainer.failures == 1 and "ended (exit code -9)" in reasons[0]
        killer = threading.Timer(0.5, os.kill, (trainer.pid, signal.SIGKILL))
        killer.start()
        there.fit(X, Y, max_epochs=200, val_fraction=0.0, trainer=trainer)
        killer.join()
        here.fit(X, Y, max_epochs=200, val_fraction=0.0)
        assert trainer.failures == 2 and "lost" in reasons[1] and "caller's process" in reasons[1]
        assert _same_weights(here, there)
    finally:
        trainer.close()


def test_an_error_in_the_child_is_raised_here_and_three_in_a_row_end_the_child():
    """The child reports a failure and the caller's own run of the loop raises the real error;
    after three in a row the caller trains from then on."""
    reasons: list[str] = []
    trainer = TrainProcess(on_failure=reasons.append)
    model, X, Y = _model(), *_points(50, 2)
    model.fit(X, Y, max_epochs=2)
    bad = torch.zeros((10, 3))  # the wrong number of inputs
    for _ in range(3):
        with pytest.raises(RuntimeError):
            trainer(model, bad, torch.zeros((10, 6)), None, torch.Generator(), 2, 1e-3)
    assert trainer.failures == 3 and "RuntimeError" in reasons[0]
    assert trainer.pid is None and "from now on" in reasons[2]
    here, there, (X, Y) = _model(), _model(), _points(100, 3)
    here.fit(X, Y, max_epochs=5)
    there.fit(X, Y, max_epochs=5, trainer=trainer)
    assert _same_weights(here, there) and trainer.trained == 0


def test_close_ends_the_child_and_later_fits_train_here():
    trainer = TrainProcess()
    pid = trainer.pid
    trainer.close()
    with pytest.raises(ChildProcessError):
        os.waitpid(pid, os.WNOHANG)  # reaped: no such child any more
    here, there, (X, Y) = _model(), _model(), _points(100, 3)
    here.fit(X, Y, max_epochs=5)
    there.fit(X, Y, max_epochs=5, trainer=trainer)
    assert _same_weights(here, there) and trainer.pid is None and trainer.failures == 0


def _running(pid: int) -> bool:
    """Whether process ``pid`` exists and is not a zombie (a container's init may not reap)."""
    try:
        with open(f"/proc/{pid}/stat") as f:
            return f.read().rsplit(")", 1)[1].split()[0] != "Z"
    except FileNotFoundError:
        return False


def test_a_child_ends_when_its_caller_is_killed_mid_fit(tmp_path):
    """A caller killed with -9 while its child trains (a daemon killed mid-fit) leaves no child
    training on: it ends within seconds, not when its fit would have ended (hours). The deadline
    allows for a child still importing torch on a loaded machine (it watches from then on)."""
    script = tmp_path / "caller.py"
    script.write_text(
        "from tests.learner.test_train_process import TrainProcess, _model, _points\n"
        "trainer = TrainProcess()\n"
        "print(trainer.pid, flush=True)\n"
        "X, Y = _points(200, 4)\n"
        "_model().fit(X, Y, max_epochs=10**6, val_fraction=0.0, trainer=trainer)\n"
    )
    root = Path(__file__).resolve().parents[2]
    env = dict(os.environ, PYTHONPATH=str(root))
    caller = subprocess.Popen([sys.executable, str(script)], stdout=subprocess.PIPE, env=env)
    try:
        child = int(caller.stdout.readline())
        time.sleep(3.0)  # the fit is under way in the child
        assert _running(child)
        caller.kill()
        caller.wait(10)
        deadline = time.monotonic() + 60
        while _running(child) and time.monotonic() < deadline:
            time.sleep(0.1)
        assert not _running(child), "the child trains on after its caller died"
    finally:
        caller.kill()
        caller.stdout.close()
