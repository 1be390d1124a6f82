"""The command protocol of the CLI and the one way results are printed."""

from __future__ import annotations

import abc
import argparse
import json
import sys
from typing import Any

from kinematics.errors import CLIUsageError  # noqa: F401 - the commands raise it from here
from learner.config import BASE_KINDS, DEFAULT_BASE


class Command(abc.ABC):
    """One CLI command: ``name`` (one or two words), ``help``, arguments and an action."""

    name: str = ""
    help: str = ""

    def add_arguments(self, parser: argparse.ArgumentParser) -> None:
        """Add this command's options; a no-op hook for commands without any."""

    @abc.abstractmethod
    def take_action(self, args: argparse.Namespace) -> int:
        """Do the work; return the exit code."""


def add_json_flag(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--json", action="store_true", help="machine-readable result on stdout")


def emit(result: dict[str, Any], as_json: bool, text: str) -> None:
    """Print ``result`` as JSON (``--json``) or the human-readable ``text``."""
    if as_json:
        json.dump(result, sys.stdout, indent=2, sort_keys=True, default=_jsonable)
        sys.stdout.write("\n")
    else:
        print(text)


def _jsonable(value: Any) -> Any:
    import numpy as np  # a result holding arrays has loaded numpy already

    if isinstance(value, np.ndarray):
        return value.tolist()
    if isinstance(value, np.generic):
        return value.item()
    raise TypeError(f"not JSON-serialisable: {type(value).__name__}")


def add_base_argument(parser: argparse.ArgumentParser, default: str = DEFAULT_BASE) -> None:
    """``--base``: the physics base whose residual the network learns."""
    parser.add_argument(
        "--base",
        default=default,
        help=f"physics base the network learns the residual of: {', '.join(BASE_KINDS)} or a "
        f"model file from `robocal calibrate`/`robocal gap` (.toml); default {default}",
    )
