"""The lock around a worker's count-and-ask step, for every storage kind.

A journal or SQLite file is locked with ``flock`` on a file beside it (one machine); a
PostgreSQL (or MySQL) study is locked in the database itself with an advisory lock named after
the study, so workers on several machines never ask for more trials than requested.
"""

from __future__ import annotations

import contextlib
import functools
import zlib
from collections.abc import Callable, Iterator
from contextlib import AbstractContextManager
from pathlib import Path

from learner.hpo_study import is_url, lock_path

Lock = Path | Callable[[], AbstractContextManager[None]] | None


def study_lock(target: str | Path, study: str) -> Lock:
    """What :func:`learner.hpo_study.run_trials` locks for ``study`` on ``target``: a lock file,
    an advisory-lock factory (PostgreSQL, MySQL) or None (another RDB: no lock)."""
    path = lock_path(target)
    if path is not None or not is_url(target):
        return path
    dialect = str(target).split("://", 1)[0].split("+", 1)[0]
    if dialect in ("postgresql", "mysql"):
        return functools.partial(_advisory_lock, str(target), study, dialect)
    return None


@contextlib.contextmanager
def _advisory_lock(url: str, study: str, dialect: str) -> Iterator[None]:
    """Hold a database advisory lock keyed by the study name while the block runs."""
    import sqlalchemy

    engine = _engine(url)
    key = zlib.crc32(f"robocal-hpo:{study}".encode())
    with engine.connect() as conn:
        if dialect == "postgresql":
            conn.execute(sqlalchemy.text("SELECT pg_advisory_lock(:k)"), {"k": key})
        else:
            conn.execute(sqlalchemy.text("SELECT GET_LOCK(:k, -1)"), {"k": str(key)})
        try:
            yield
        finally:
            if dialect == "postgresql":
                conn.execute(sqlalchemy.text("SELECT pg_advisory_unlock(:k)"), {"k": key})
            else:
                conn.execute(sqlalchemy.text("SELECT RELEASE_LOCK(:k)"), {"k": str(key)})


@functools.cache
def _engine(url: str):  # noqa: ANN202 - sqlalchemy.Engine, imported lazily
    import sqlalchemy

    return sqlalchemy.create_engine(url, poolclass=sqlalchemy.pool.NullPool)
