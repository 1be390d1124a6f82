"""State files of the daemon: atomic writes that leave no temporary file behind, and the
check that a state directory is writable before anything starts.

>>> import tempfile, pathlib
>>> d = pathlib.Path(tempfile.mkdtemp())
>>> write_atomic(d / "x.json", b"{}").read_bytes(), sorted(p.name for p in d.iterdir())
(b'{}', ['x.json'])
"""

from __future__ import annotations

import errno
import os
import tempfile
from pathlib import Path

from kinematics.errors import RobocalError
from learner.snapshot import atomic_write_bytes as write_atomic  # noqa: F401 (the one writer)


class StateDirError(RobocalError):
    """A state directory or file that cannot be written (full disk, read-only, permissions)."""


def remove_temporaries(path: str | Path) -> int:
    """Remove the temporary files that atomic writes of ``path`` left (``.<name>.*``); count."""
    path = Path(path)
    n = 0
    for tmp in path.parent.glob(f".{path.name}.*"):
        tmp.unlink(missing_ok=True)
        n += 1
    return n


def check_writable(directory: str | Path, what: str) -> Path:
    """Create ``directory`` if needed and prove it writable; StateDirError in one line."""
    d = Path(directory)
    try:
        d.mkdir(parents=True, exist_ok=True)
        fd, probe = tempfile.mkstemp(dir=d, prefix=".robocal-probe.")
        os.close(fd)
        os.unlink(probe)
    except OSError as exc:
        raise StateDirError(f"{what} {d} is not writable: {describe_os_error(exc)}") from None
    return d


def describe_os_error(exc: BaseException) -> str:
    """One line for an OSError: ``[ENOSPC] No space left on device: '/x'``."""
    if isinstance(exc, OSError) and exc.errno is not None:
        name = errno.errorcode.get(exc.errno, str(exc.errno))
        where = f": {exc.filename!r}" if exc.filename else ""
        return f"[{name}] {exc.strerror}{where}"
    return f"{type(exc).__name__}: {exc}"
