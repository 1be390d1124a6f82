"""The command protocol of the CLI and the one way results are printed."""

from __future__ import annotations

import abc
import argparse
import json
import os
import sys
import tempfile
from pathlib import Path
from typing import TYPE_CHECKING, Any

from kinematics.errors import CLIUsageError  # noqa: F401 - the commands raise it from here
from learner.config import BASE_KINDS, DEFAULT_BASE

if TYPE_CHECKING:
    from kinematics.dataset import Dataset


class Command(abc.ABC):
    """One CLI command: ``name`` (one or two words), ``help``, arguments and an action."""

    name: str = ""
    help: str = ""
    #: False for commands that never touch torch: main() then leaves it unimported.
    uses_torch: bool = True

    def add_arguments(self, parser: argparse.ArgumentParser) -> None:
        """Add this command's options; a no-op hook for commands without any."""

    @abc.abstractmethod
    def take_action(self, args: argparse.Namespace) -> int:
        """Do the work; return the exit code."""


#: Options naming a file or folder a command writes. main() proves each one's folder writable
#: before the command starts, so a long run never ends in a write error it could have seen.
OUTPUT_OPTIONS = ("out", "hist", "report")


def check_outputs(args: argparse.Namespace) -> None:
    """CLIUsageError naming the option, path and reason when an output's folder cannot be
    written (it is created if missing; a probe file is written there and removed)."""
    for name in OUTPUT_OPTIONS:
        value = getattr(args, name, None)
        if not isinstance(value, str):
            continue
        path = Path(value)
        existing = next(p for p in (path.parent, *path.parent.parents) if p.exists())
        if not existing.is_dir():
            raise CLIUsageError(f"--{name} {value}: {existing} is a file, not a folder")
        try:
            path.parent.mkdir(parents=True, exist_ok=True)
            fd, probe = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=".probe")
            os.close(fd)
            os.unlink(probe)
        except OSError as exc:
            reason = os.strerror(exc.errno) if exc.errno else str(exc)
            raise CLIUsageError(f"--{name} {value}: cannot write there: {reason}") from None


def add_data_argument(parser: argparse.ArgumentParser, robot: bool = False) -> None:
    """``--data``, the dataset file a command reads, and with ``robot`` the ``--robot``
    description it is scored against (default: the one its metadata names)."""
    parser.add_argument("--data", required=True, help="dataset file (.parquet or .csv)")
    if robot:
        parser.add_argument("--robot", default=None, help="robot description (default: meta)")


def notice(message: str) -> None:
    """One line on stderr about what a command dropped from its input (not an error)."""
    print(f"robocal: {message}", file=sys.stderr)


def read_data(args: argparse.Namespace) -> Dataset:
    """The ``--data`` series (against ``--robot`` where the command has it), read by
    :func:`kinematics.series.read_series`: the rows it drops are named on stderr."""
    from kinematics.series import read_series

    return read_series(args.data, getattr(args, "robot", None), notice)[1]


class ProgressBar:
    """A tqdm bar on stderr, drawn at its first use inside the ``with`` block and not before:
    an error in a command's set-up is then the only thing it prints. Reads and calls go to
    the bar (``bar.update()``, ``bar.n``); set its position with ``update``, not ``bar.n =``.
    """

    def __init__(self, **kwargs: Any) -> None:
        self._kwargs = kwargs
        self._bar = None

    def __getattr__(self, name: str) -> Any:
        if self._bar is None:
            from tqdm import tqdm

            self._bar = tqdm(file=sys.stderr, **self._kwargs)
        return getattr(self._bar, name)

    def __enter__(self) -> ProgressBar:
        return self

    def __exit__(self, *exc: object) -> None:
        if self._bar is not None:
            self._bar.close()


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


def add_base_argument(
    parser: argparse.ArgumentParser,
    default: str = DEFAULT_BASE,
    kinds: tuple[str, ...] = BASE_KINDS,
) -> None:
    """``--base``: the physics base whose residual the network learns."""
    parser.add_argument(
        "--base",
        default=default,
        help=f"physics base the network learns the residual of: {', '.join(kinds)} or a "
        f"model file from `robocal calibrate`/`robocal gap` (.toml); default {default}",
    )
