"""The search's configuration and its trial budget: how many epochs a trial's folds may train.

A trial's epochs are capped by a fixed amount of *work*: one training row through one weight
(forward and backward) is a unit, and an optimiser step costs ``STEP_OVERHEAD`` units per
weight (Adam and the gradient passes read every weight once per step, whatever the batch). So
an epoch of a trial costs ``weights * rows * (1 + STEP_OVERHEAD / batch_size)`` and the epoch
budget is ``min(max_epochs, work / that)``: it shrinks with the data size (a 3,004-point
campaign gets a tenth of a 300-point one's epochs, the same number of gradient steps) and with
the network (a 15 x 500 network at batch 4 gets a few epochs, the default 3 x 64 all of them).
The cap is arithmetic, not a clock: the same seed runs the same trials on any machine.

>>> trial_epochs(n_weights=100_000, rows=270, batch_size=32, max_epochs=200, work=5e11)
200
>>> trial_epochs(n_weights=37_000_000, rows=270, batch_size=6, max_epochs=200, work=5e11)
1
"""

from __future__ import annotations

import math
import os
from dataclasses import dataclass

from kinematics.errors import ConfigError

#: Units of work per weight of one optimiser step, in training rows: measured 233 on the
#: reference machine (a 10 x 259 ensemble of 60 heads, 1 thread: 281 ms a step at 6 rows,
#: 309 ms at 30 rows; BENCHMARKS.md, "Hyperparameter search").
STEP_OVERHEAD = 233.0
#: Default work per trial (units above): about 16 s of one core of the reference machine.
TRIAL_WORK = 5e11


@dataclass(frozen=True, kw_only=True)
class HpoConfig:
    """The search: trial budget, CV folds, epochs per fold (capped by ``trial_work``, see the
    module docstring), Hyperband rungs, selection, and whether the folds of a trial train as
    one batched model (:mod:`learner.hpo_batched`) or one after the other. ``timeout_s`` (s)
    bounds the whole search, the running trial included. ``defaults_first``: trial 0 is the
    learner's default configs; selection takes the fewest weights among the ``top_k`` best
    within ``select_within`` (fraction of the best CV score)."""

    trials: int = 50
    timeout_s: float | None = None
    folds: int = 5
    max_epochs: int = 200
    min_epochs: int = 10
    trial_work: float = TRIAL_WORK
    batched_folds: bool = True
    reduction_factor: int = 3
    startup_trials: int = 10
    prune: bool = True
    top_k: int = 10
    select_within: float = 0.1
    defaults_first: bool = True
    seed: int = 0
    study: str = "robocal-hpo"

    def __post_init__(self) -> None:
        for key in ("trials", "max_epochs", "min_epochs", "top_k", "startup_trials"):
            value = getattr(self, key)
            if not isinstance(value, int) or isinstance(value, bool) or value < 1:
                raise ConfigError(f"hpo.{key} must be an int >= 1, got {value!r}")
        if not isinstance(self.folds, int) or self.folds < 2:
            raise ConfigError(f"hpo.folds must be an int >= 2, got {self.folds!r}")
        if not isinstance(self.reduction_factor, int) or self.reduction_factor < 2:
            raise ConfigError(
                f"hpo.reduction_factor must be an int >= 2, got {self.reduction_factor!r}"
            )
        if self.min_epochs > self.max_step:
            raise ConfigError(
                f"hpo.min_epochs must be <= the last step {self.max_step}, got {self.min_epochs}"
            )
        if self.timeout_s is not None and not self.timeout_s > 0:
            raise ConfigError(f"hpo.timeout_s must be > 0, got {self.timeout_s}")
        if not self.trial_work > 0:
            raise ConfigError(f"hpo.trial_work must be > 0 (inf: no cap), got {self.trial_work}")
        if not self.select_within >= 0:
            raise ConfigError(f"hpo.select_within must be >= 0, got {self.select_within}")
        if not self.study:
            raise ConfigError("hpo.study must be a non-empty name, got ''")

    @property
    def max_step(self) -> int:
        """The last step a trial reports: an epoch of all folds at once when batched, else
        every epoch of every fold (fold-major)."""
        return self.max_epochs if self.batched_folds else self.folds * self.max_epochs


def trial_epochs(
    *, n_weights: int, rows: int, batch_size: int, max_epochs: int, work: float
) -> int:
    """Epochs a trial may train: ``max_epochs`` capped by ``work`` (at least one).

    ``n_weights`` are all folds' weights together, ``rows`` the training rows of a fold.
    """
    per_epoch = n_weights * rows * (1.0 + STEP_OVERHEAD / max(1, min(batch_size, rows)))
    if not math.isfinite(work):
        return max_epochs
    return int(max(1, min(max_epochs, math.floor(work / per_epoch))))


def default_threads(workers: int = 1) -> int:
    """Torch threads per worker process: the idle cores (those this process may use less the
    1-minute load average), shared by the workers, at least one.

    More threads than idle cores is the worst case: on the 2-core reference machine under
    others' load a 10 x 259 trial took 89 s at 2 threads and 14 s at 1 (BENCHMARKS.md).
    """
    cores = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count()
    cores = cores or 1
    idle = cores - round(os.getloadavg()[0]) if hasattr(os, "getloadavg") else cores
    return max(1, min(cores, idle) // max(1, workers))
