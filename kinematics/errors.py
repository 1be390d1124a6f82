"""One root error for robocal and its narrow subclasses.

Every message is one line that names what was wrong (expected vs got). The CLI prints the
line and exits 2; ``--debug`` shows the traceback.
"""

import math


class RobocalError(Exception):
    """Root of every error robocal raises on purpose."""


class ConfigError(RobocalError):
    """A configuration value or file is invalid."""


class DescriptionError(RobocalError):
    """A robot description (TOML or URDF) is malformed or inconsistent."""


class DatasetError(RobocalError):
    """A dataset file is missing columns, has non-finite values or violates limits."""


class SchemaError(RobocalError):
    """A message on the bus does not match its schema."""


class SnapshotError(RobocalError):
    """A model snapshot cannot be read or does not match the data."""


class IdentifiabilityError(RobocalError):
    """The data cannot determine the requested parameters (too few or unexciting poses)."""


class CLIUsageError(RobocalError):
    """Command-line arguments that parse but make no sense together."""


def check_positive(section: str, config: object, *names: str) -> None:
    """Raise ``ConfigError("<section>.<name> must be > 0, got <value>")`` for the first of the
    ``names`` attributes of ``config`` that is not a finite number > 0.

    >>> from types import SimpleNamespace
    >>> check_positive("window", SimpleNamespace(a=1.0, b=float("inf")), "a", "b")
    Traceback (most recent call last):
    ...
    kinematics.errors.ConfigError: window.b must be > 0, got inf
    """
    for name in names:
        value = getattr(config, name)
        if not (math.isfinite(value) and value > 0):
            raise ConfigError(f"{section}.{name} must be > 0, got {value}")
