"""CLI commands of the learner: ``train``, ``continual``, ``evaluate``, ``experiment paper``."""

from stream.cli._base import Command

COMMANDS: tuple[type[Command], ...] = ()
