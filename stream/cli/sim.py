"""CLI commands of the simulated cell: ``sim dataset``."""

from stream.cli._base import Command

COMMANDS: tuple[type[Command], ...] = ()
