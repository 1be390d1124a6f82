"""CLI command ``gap``: the sim-vs-measured discrepancy workflow."""

from stream.cli._base import Command

COMMANDS: tuple[type[Command], ...] = ()
