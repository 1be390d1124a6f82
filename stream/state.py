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


class StateDirError(RobocalError):
    """A state directory or file that cannot be written (full disk, read-only, permissions)."""


def write_atomic(path: str | Path, data: bytes) -> Path:
    """Write ``data`` to ``path`` via a temporary file and a rename; on any failure the
    temporary file is removed and ``path`` keeps its previous content (OSError re-raised)."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=".tmp")
    try:
        with os.fdopen(fd, "wb") as f:
            f.write(data)
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise
    return path


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
