"""One root error for robocal and its narrow subclasses.

Every message is one line that names what was wrong (expected vs got). The CLI prints the
line and exits 2; ``--debug`` shows the traceback.
"""


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
