"""CLI commands of the live pipeline: ``run`` (daemon) and ``demo``."""

from stream.cli._base import Command

COMMANDS: tuple[type[Command], ...] = ()
