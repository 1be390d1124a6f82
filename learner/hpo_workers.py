"""Helper worker processes on one machine: more trials of one study at the same time.

``robocal hpo --workers N`` runs the search in its own process and ``N - 1`` helpers started
here (``spawn``: a fresh interpreter, no inherited torch thread pools). A helper opens the same
storage and runs trials until the study holds the requested number (the count-and-ask rule of
:func:`learner.hpo_study.run_trials`); the first process then selects and retrains. Workers on
other machines are just more ``robocal hpo`` processes on the same RDB storage URL.
"""

from __future__ import annotations

import multiprocessing
import time
from multiprocessing.process import BaseProcess
from pathlib import Path

import numpy as np
import optuna

from learner.base import PhysicsBase
from learner.features import FeatureSpec
from learner.hpo_config import HpoConfig
from learner.hpo_lock import study_lock
from learner.hpo_objective import cv_objective
from learner.hpo_space import SearchSpace, learner_defaults
from learner.hpo_study import make_study, open_storage, run_trials
from learner.training import set_compute_threads


def open_study(cfg: HpoConfig, storage: str | Path) -> optuna.Study:
    """Create or load ``cfg.study`` on ``storage`` with the config's sampler and pruner."""
    return make_study(
        open_storage(storage),
        cfg.study,
        seed=cfg.seed,
        max_resource=cfg.max_step,
        min_resource=cfg.min_epochs,
        reduction_factor=cfg.reduction_factor,
        prune=cfg.prune,
        n_startup_trials=cfg.startup_trials,
    )


def start_workers(
    n: int,
    spec: FeatureSpec,
    X: np.ndarray,
    Y: np.ndarray,
    cfg: HpoConfig,
    storage: str | Path,
    *,
    space: SearchSpace,
    base: PhysicsBase | None,
    deadline: float | None,
    threads: int,
) -> list[BaseProcess]:
    """Start ``n`` helper processes running trials of ``cfg.study`` on ``storage`` (each with
    ``threads`` torch threads, stopping asking at ``deadline``, ``time.monotonic()`` s)."""
    ctx = multiprocessing.get_context("spawn")
    procs = [
        ctx.Process(
            target=_work,
            args=(spec, X, Y, cfg, str(storage), space, base, deadline, threads),
            name=f"robocal-hpo-worker-{k + 1}",
        )
        for k in range(n)
    ]
    for p in procs:
        p.start()
    return procs


def wait_workers(procs: list[BaseProcess], *, stop: bool = False) -> list[int]:
    """Join the helpers (terminate them first when ``stop``); their exit codes."""
    for p in procs:
        if stop and p.is_alive():
            p.terminate()
        p.join()
    return [int(p.exitcode or 0) for p in procs]


def _work(
    spec: FeatureSpec,
    X: np.ndarray,
    Y: np.ndarray,
    cfg: HpoConfig,
    storage: str,
    space: SearchSpace,
    base: PhysicsBase | None,
    deadline: float | None,
    threads: int,
) -> None:
    set_compute_threads(threads)  # BLAS too, as the CLI and the daemon cap it
    optuna.logging.set_verbosity(optuna.logging.WARNING)
    study = open_study(cfg, storage)
    left = None if deadline is None else max(0.0, deadline - time.monotonic())
    if left == 0.0:
        return
    objective = cv_objective(spec, X, Y, space, cfg, base, deadline)
    first = learner_defaults(space) if cfg.defaults_first else None
    lock = study_lock(storage, cfg.study)
    run_trials(study, objective, cfg.trials, timeout_s=left, lock=lock, first=first)
