"""The hyperparameter search space of DESIGN.md, overridable from a small TOML file.

Every range is ``[low, high]`` inclusive; ``lr`` and ``weight_decay`` are sampled on a log
scale. A TOML file names only the ranges it changes:

.. code-block:: toml

    hidden_layers = [1, 3]
    neurons = [16, 64]
    activations = ["relu", "gelu"]
    lr = [1e-4, 1e-2]

>>> s = space_from_dict({"hidden_layers": [1, 3], "activations": ["relu"]})
>>> s.hidden_layers, s.neurons, s.activations
((1, 3), (50, 500), ('relu',))
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass, fields
from pathlib import Path

import optuna

from kinematics.errors import ConfigError
from kinematics.toml_io import load_toml
from learner.config import ModelConfig, TrainConfig

ACTIVATIONS = ("elu", "relu", "gelu")


@dataclass(frozen=True, kw_only=True)
class SearchSpace:
    """Inclusive ranges of the searched hyperparameters (SI-free: counts, rates, fractions)."""

    hidden_layers: tuple[int, int] = (1, 15)
    neurons: tuple[int, int] = (50, 500)
    activations: tuple[str, ...] = ACTIVATIONS
    batch_size: tuple[int, int] = (4, 64)
    lr: tuple[float, float] = (1e-7, 1e-2)
    weight_decay: tuple[float, float] = (1e-7, 1e-2)
    dropout: tuple[float, float] = (0.0, 0.5)

    def __post_init__(self) -> None:
        for name in ("hidden_layers", "neurons", "batch_size"):
            _check_range(self, name, integer=True, low_min=1)
        for name in ("lr", "weight_decay"):
            _check_range(self, name, integer=False, low_min=None)
            if getattr(self, name)[0] <= 0:
                raise ConfigError(
                    f"space.{name} is log-scaled and must be > 0, got {list(getattr(self, name))}"
                )
        _check_range(self, "dropout", integer=False, low_min=0.0)
        if self.dropout[1] >= 1.0:
            raise ConfigError(f"space.dropout must stay below 1, got {list(self.dropout)}")
        acts = tuple(self.activations)
        if not acts or any(a not in ACTIVATIONS for a in acts) or len(set(acts)) != len(acts):
            raise ConfigError(
                f"space.activations must be distinct names from {ACTIVATIONS}, got {list(acts)}"
            )
        object.__setattr__(self, "activations", acts)


@dataclass(frozen=True, kw_only=True)
class TrialParams:
    """One point of the space: what a trial trains with."""

    hidden_layers: int
    neurons: int
    activation: str
    batch_size: int
    lr: float
    weight_decay: float
    dropout: float

    @classmethod
    def from_dict(cls, params: dict) -> TrialParams:
        """From a trial's ``params`` (Optuna names equal the field names)."""
        return cls(**{f.name: params[f.name] for f in fields(cls)})


def suggest(trial: optuna.Trial, space: SearchSpace) -> TrialParams:
    """Ask ``trial`` for one point of ``space`` (log scale for the learning rate and decay)."""
    return TrialParams(
        hidden_layers=trial.suggest_int("hidden_layers", *space.hidden_layers),
        neurons=trial.suggest_int("neurons", *space.neurons),
        activation=trial.suggest_categorical("activation", list(space.activations)),
        batch_size=trial.suggest_int("batch_size", *space.batch_size),
        lr=trial.suggest_float("lr", *space.lr, log=True),
        weight_decay=trial.suggest_float("weight_decay", *space.weight_decay, log=True),
        dropout=trial.suggest_float("dropout", *space.dropout),
    )


def learner_defaults(space: SearchSpace) -> dict | None:
    """The learner's default configs as parameters of ``space`` (None where the space excludes
    them): a search's first trial, so every study scores the defaults on its own folds."""
    learner = asdict(TrainConfig()) | asdict(ModelConfig())
    p = TrialParams(**{f.name: learner[f.name] for f in fields(TrialParams)})
    ranged = [f.name for f in fields(SearchSpace) if f.name != "activations"]
    inside = all(getattr(space, k)[0] <= getattr(p, k) <= getattr(space, k)[1] for k in ranged)
    return asdict(p) if inside and p.activation in space.activations else None


def space_from_dict(raw: dict) -> SearchSpace:
    """A space from parsed TOML: known keys only, each a two-element list (or activation names)."""
    known = {f.name for f in fields(SearchSpace)}
    unknown = sorted(set(raw) - known)
    if unknown:
        raise ConfigError(
            f"unknown search-space key(s) {unknown}; expected some of {sorted(known)}"
        )
    values = {}
    for key, value in raw.items():
        if not isinstance(value, list | tuple):
            raise ConfigError(f"space.{key} must be a list, got {value!r}")
        if key != "activations" and len(value) != 2:
            raise ConfigError(f"space.{key} must be [low, high], got {list(value)}")
        values[key] = tuple(value)
    return SearchSpace(**values)


def load_space(path: str | Path) -> SearchSpace:
    """Read a search-space TOML file; errors name the file and the bad value."""
    return load_toml(path, "search-space file", space_from_dict)


def _check_range(space: SearchSpace, name: str, integer: bool, low_min: float | None) -> None:
    value = getattr(space, name)
    kind = int if integer else (int, float)
    if (
        len(value) != 2
        or any(isinstance(v, bool) or not isinstance(v, kind) for v in value)
        or not all(math.isfinite(v) for v in value)
    ):
        what = "integers" if integer else "finite numbers"
        raise ConfigError(f"space.{name} must be two {what} [low, high], got {list(value)}")
    low, high = value
    if low > high or (low_min is not None and low < low_min):
        bound = f" with low >= {low_min}" if low_min is not None else ""
        raise ConfigError(f"space.{name} must satisfy low <= high{bound}, got {list(value)}")
    if not integer:
        object.__setattr__(space, name, (float(low), float(high)))
