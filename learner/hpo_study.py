"""Optuna plumbing of the search: storage, a resumable shared study, the worker loop, selection.

A study lives in a storage several processes can share: by default an append-only journal file
(``JournalStorage`` + ``JournalFileBackend``; it survives a crash and ``optuna-dashboard FILE``
reads it), or any RDB URL (``sqlite:///hpo.db``). Every worker counts the trials that are
finished or still running in the whole study and asks for a new one only while that count is
below the requested total, so a stopped study resumes where it stopped and two workers on one
storage run exactly the requested number of trials together. The count-and-ask step holds a
lock: a file lock beside a journal or SQLite file, or a database advisory lock on PostgreSQL
(:mod:`learner.hpo_lock`); running trials left behind by a
crashed worker on this host are marked failed (and so redone).
"""

from __future__ import annotations

import contextlib
import math
import os
import socket
import time
import zlib
from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import optuna
import psutil
from filelock import FileLock
from optuna.distributions import BaseDistribution
from optuna.samplers import BaseSampler, TPESampler
from optuna.storages import BaseStorage, JournalStorage, RDBStorage
from optuna.storages.journal import JournalFileBackend
from optuna.trial import FrozenTrial, TrialState

from kinematics.errors import ConfigError

COUNTED = (TrialState.COMPLETE, TrialState.PRUNED, TrialState.RUNNING, TrialState.WAITING)
FINISHED = (TrialState.COMPLETE, TrialState.PRUNED)
WORKER_ATTR = "worker"

Objective = Callable[[optuna.Trial], float]


class TrialSeededTPE(BaseSampler):
    """TPE whose random stream is seeded by ``(seed, trial number)``.

    A plain ``TPESampler(seed=s)`` restarts the same random stream in every process, so a
    resumed study or a second worker would repeat the first trials' parameters. Seeding each
    trial from its (unique) number keeps runs reproducible without such repeats.
    """

    def __init__(self, seed: int, n_startup_trials: int = 10) -> None:
        self._seed = seed
        self._n_startup = n_startup_trials
        self._tpe = TPESampler(seed=seed, n_startup_trials=n_startup_trials)

    def before_trial(self, study: optuna.Study, trial: FrozenTrial) -> None:
        mixed = zlib.crc32(f"{self._seed}:{trial.number}".encode())
        self._tpe = TPESampler(seed=mixed, n_startup_trials=self._n_startup)
        self._tpe.before_trial(study, trial)

    def infer_relative_search_space(
        self, study: optuna.Study, trial: FrozenTrial
    ) -> dict[str, BaseDistribution]:
        return self._tpe.infer_relative_search_space(study, trial)

    def sample_relative(
        self, study: optuna.Study, trial: FrozenTrial, search_space: dict[str, BaseDistribution]
    ) -> dict[str, Any]:
        return self._tpe.sample_relative(study, trial, search_space)

    def sample_independent(
        self,
        study: optuna.Study,
        trial: FrozenTrial,
        param_name: str,
        param_distribution: BaseDistribution,
    ) -> Any:
        return self._tpe.sample_independent(study, trial, param_name, param_distribution)

    def after_trial(
        self,
        study: optuna.Study,
        trial: FrozenTrial,
        state: TrialState,
        values: Sequence[float] | None,
    ) -> None:
        self._tpe.after_trial(study, trial, state, values)

    def reseed_rng(self) -> None:
        self._tpe.reseed_rng()


def is_url(target: str | Path) -> bool:
    """True for an RDB URL (``sqlite:///x.db``), False for a journal file path."""
    return "://" in str(target)


def open_storage(target: str | Path) -> BaseStorage:
    """An RDB storage for a URL, else a journal file (created with its folder).

    Workers starting together on an empty database race to create Optuna's tables and all
    but one fail; opening is tried three times (0.5 s apart), the later tries find the tables.
    """
    if is_url(target):
        reason = ""
        for attempt in range(3):
            try:
                return RDBStorage(str(target))
            except Exception as exc:  # sqlalchemy raises many kinds for a bad URL
                reason = str(exc).splitlines()[0] if str(exc) else type(exc).__name__
                if attempt < 2:
                    time.sleep(0.5)
        raise ConfigError(f"storage {target}: cannot open: {reason}")
    path = Path(target)
    if path.is_dir():
        raise ConfigError(f"storage {path}: expected a journal file, got a folder")
    path.parent.mkdir(parents=True, exist_ok=True)
    return JournalStorage(JournalFileBackend(str(path)))


def lock_path(target: str | Path) -> Path | None:
    """The file locked around count-and-ask: beside a journal or SQLite file, None otherwise."""
    text = str(target)
    if text.startswith("sqlite:///"):
        return Path(text[len("sqlite:///") :] + ".hpo-lock")
    if is_url(text):
        return None
    return Path(text + ".hpo-lock")


def make_study(
    storage: BaseStorage,
    name: str,
    *,
    seed: int,
    max_resource: int,
    min_resource: int = 1,
    reduction_factor: int = 3,
    prune: bool = True,
    n_startup_trials: int = 10,
) -> optuna.Study:
    """Create or load (``load_if_exists``) a minimising study with seeded TPE and Hyperband.

    ``max_resource`` is the last step a trial reports; ``prune=False`` uses ``NopPruner`` (the
    same search without early termination, e.g. to measure what pruning saves). With Hyperband,
    TPE models each bracket's trials apart, so ``n_startup_trials`` random trials come per bracket.
    """
    pruner: optuna.pruners.BasePruner = (
        optuna.pruners.HyperbandPruner(
            min_resource=min_resource,
            max_resource=max_resource,
            reduction_factor=reduction_factor,
        )
        if prune
        else optuna.pruners.NopPruner()
    )
    return optuna.create_study(
        storage=storage,
        study_name=name,
        sampler=TrialSeededTPE(seed, n_startup_trials),
        pruner=pruner,
        direction="minimize",
        load_if_exists=True,
    )


@dataclass(frozen=True, kw_only=True)
class Progress:
    """What a worker knows after one of its trials (``trial``; None: before its first, once
    the study is open): the study's finished count and best value."""

    finished: int
    total: int
    trial: FrozenTrial | None
    best_value: float | None


def run_trials(
    study: optuna.Study,
    objective: Objective,
    n_trials: int,
    *,
    timeout_s: float | None = None,
    lock: Path | Callable[[], contextlib.AbstractContextManager[None]] | None = None,
    on_trial: Callable[[Progress], None] | None = None,
    first: dict[str, Any] | None = None,
) -> list[int]:
    """Run trials until the study holds ``n_trials`` finished or running ones (or the timeout
    passes); return the numbers of the trials this worker ran. ``first`` (parameters) is
    enqueued as trial 0 of an empty study, under the lock, so it runs once whatever the workers.

    ``objective`` may raise ``optuna.TrialPruned``; any other exception fails the trial and
    propagates.
    """
    if n_trials < 1:
        raise ConfigError(f"hpo trials must be >= 1, got {n_trials}")
    start = time.monotonic()
    mine: list[int] = []
    if on_trial is not None:
        on_trial(_progress(study, n_trials, None))
    while timeout_s is None or time.monotonic() - start < timeout_s:
        with lock() if callable(lock) else _file_lock(lock):
            fail_stale_trials(study)
            if len(study.get_trials(deepcopy=False, states=COUNTED)) >= n_trials:
                break
            if first is not None and not study.get_trials(deepcopy=False):
                study.enqueue_trial(first)
            trial = study.ask()
            trial.set_user_attr(WORKER_ATTR, _worker_id())
        mine.append(trial.number)
        try:
            frozen = study.tell(trial, objective(trial))
        except optuna.TrialPruned:
            frozen = study.tell(trial, state=TrialState.PRUNED)
        except BaseException:
            study.tell(trial, state=TrialState.FAIL)
            raise
        if on_trial is not None:
            on_trial(_progress(study, n_trials, frozen))
    return mine


def _progress(study: optuna.Study, n_trials: int, trial: FrozenTrial | None) -> Progress:
    return Progress(
        finished=len(study.get_trials(deepcopy=False, states=FINISHED)),
        total=n_trials,
        trial=trial,
        best_value=best_value(study),
    )


def best_value(study: optuna.Study) -> float | None:
    """The lowest complete value so far, or None before the first complete trial."""
    done = study.get_trials(deepcopy=False, states=(TrialState.COMPLETE,))
    return min(t.value for t in done) if done else None


def fail_stale_trials(study: optuna.Study) -> list[int]:
    """Mark failed the running trials whose worker process on this host no longer exists."""
    host = socket.gethostname()
    stale = []
    for t in study.get_trials(deepcopy=False, states=(TrialState.RUNNING,)):
        worker = str(t.user_attrs.get(WORKER_ATTR, ""))
        worker_host, _, pid = worker.rpartition(":")
        if worker_host == host and pid.isdigit() and not _alive(int(pid)):
            study.tell(t.number, state=TrialState.FAIL, skip_if_finished=True)
            stale.append(t.number)
    return stale


def top_trials(study: optuna.Study, k: int) -> list[FrozenTrial]:
    """The ``k`` complete trials with the lowest finite values, best first (a trial whose
    training diverged in every epoch of a fold scores infinity and is never selected)."""
    done = study.get_trials(deepcopy=False, states=(TrialState.COMPLETE,))
    finite = [t for t in done if math.isfinite(t.value)]
    return sorted(finite, key=lambda t: (t.value, t.number))[:k]


def select_trial(study: optuna.Study, top_k: int = 10, within: float = 0.1) -> FrozenTrial:
    """Among the ``top_k`` best complete trials that score within ``within`` (a fraction) of
    the best value, the one with the fewest weights (user attribute ``n_weights``; ties go to
    the lower value). DESIGN.md's "ten best" alone picked, in a 30-trial study whose work
    budget starves deep networks, a trial 33 x worse than the best (BENCHMARKS.md, issue 17)."""
    best = top_trials(study, top_k)
    if not best:
        raise ConfigError(f"study {study.study_name!r} has no complete trial to select from")
    close = [t for t in best if t.value <= best[0].value * (1.0 + within)]
    return min(close, key=lambda t: (t.user_attrs.get("n_weights", float("inf")), t.value))


def _worker_id() -> str:
    return f"{socket.gethostname()}:{os.getpid()}"


def _alive(pid: int) -> bool:
    """Whether process ``pid`` exists on this host (another user's counts as alive)."""
    return psutil.pid_exists(pid)


@contextlib.contextmanager
def _file_lock(path: Path | None) -> Iterator[None]:
    """An exclusive ``flock`` on ``path`` (no-op for None), taken through ``filelock`` (which
    owns the OS locking): one worker counts and asks at a time."""
    if path is None:
        yield
        return
    path.parent.mkdir(parents=True, exist_ok=True)
    with FileLock(path):
        yield
