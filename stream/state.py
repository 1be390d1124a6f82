"""State files of the daemon: atomic writes that leave no temporary file behind, the check
that a state directory is writable before anything starts, and the fsync'd log of what a stage
accepted since its last checkpoint (so a ``kill -9`` loses nothing it accepted).

>>> import tempfile, pathlib
>>> d = pathlib.Path(tempfile.mkdtemp())
>>> write_atomic(d / "x.json", b"{}").read_bytes(), sorted(p.name for p in d.iterdir())
(b'{}', ['x.json'])
"""

from __future__ import annotations

import contextlib
import errno
import os
import struct
import tempfile
import zlib
from pathlib import Path

from kinematics.errors import RobocalError
from learner.snapshot import atomic_write_bytes as write_atomic  # noqa: F401 (the one writer)


class StateDirError(RobocalError):
    """A state directory or file that cannot be written (full disk, read-only, permissions)."""


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


class AcceptedLog:
    """An append-only, fsync'd log of payloads accepted since the last checkpoint.

    Each record is ``u32 length | u32 crc32 | payload`` (little-endian). A record torn by a
    ``kill -9`` mid-write fails its length or CRC and ends the reading; what came before stands.
    The owner replays :meth:`records` after restoring its checkpoint and :meth:`clear` s the log
    once a checkpoint covers them.
    """

    def __init__(self, path: str | Path) -> None:
        self.path = Path(path)

    def append(self, payload: bytes) -> None:
        """Add one record and make it durable (fsync) before returning."""
        data = struct.pack("<II", len(payload), zlib.crc32(payload)) + payload
        self.path.parent.mkdir(parents=True, exist_ok=True)
        fd = os.open(self.path, os.O_WRONLY | os.O_APPEND | os.O_CREAT, 0o666)
        try:
            start = os.lseek(fd, 0, os.SEEK_END)
            try:
                view = memoryview(data)
                while view:
                    view = view[os.write(fd, view) :]
                os.fsync(fd)
            except OSError:  # a full disk: leave no partial record behind
                with contextlib.suppress(OSError):
                    os.ftruncate(fd, start)
                raise
        finally:
            os.close(fd)

    def records(self) -> list[bytes]:
        """The intact records, oldest first (none when the file is missing)."""
        if not self.path.exists():
            return []
        data, out, i = self.path.read_bytes(), [], 0
        while i + 8 <= len(data):
            n, crc = struct.unpack_from("<II", data, i)
            payload = data[i + 8 : i + 8 + n]
            if len(payload) != n or zlib.crc32(payload) != crc:
                break
            out.append(payload)
            i += 8 + n
        return out

    def clear(self) -> None:
        """Empty the log (after a checkpoint that holds every record)."""
        if self.path.exists():
            with self.path.open("r+b") as f:
                f.truncate(0)
                os.fsync(f.fileno())
