"""CLI command ``hpo``: Optuna search over the evidential ensemble."""

from stream.cli._base import Command

COMMANDS: tuple[type[Command], ...] = ()
