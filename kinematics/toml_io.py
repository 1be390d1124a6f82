"""Reading TOML files into typed values, with one-line errors that name the file."""

from __future__ import annotations

import tomllib
from collections.abc import Callable
from pathlib import Path
from typing import TypeVar

from kinematics.errors import ConfigError, RobocalError

T = TypeVar("T")


def load_toml(
    path: str | Path,
    what: str,
    build: Callable[[dict], T],
    error: type[RobocalError] = ConfigError,
) -> T:
    """``build(parsed TOML of path)``; a missing file, bad TOML or an ``error`` from ``build``
    raises ``error`` with the file name in front (``what`` names the file, e.g. "config file")."""
    path = Path(path)
    if not path.exists():
        raise error(f"{path}: {what} not found")
    try:
        raw = tomllib.loads(path.read_text())
    except tomllib.TOMLDecodeError as exc:
        raise error(f"{path}: invalid TOML: {exc}") from None
    try:
        return build(raw)
    except error as exc:
        raise error(f"{path}: {exc}") from None
