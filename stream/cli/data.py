"""CLI commands on datasets: ``import ipa`` and ``data summary``."""

from stream.cli._base import Command

COMMANDS: tuple[type[Command], ...] = ()
