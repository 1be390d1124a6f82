"""The dataset format of DESIGN.md: one row per measured point, Parquet or CSV + meta sidecar.

Columns: ``t`` (s), ``q1..q6`` (rad, controller), optional ``qs1..qs6`` (rad, secondary
encoders), optional ``temp_<name>`` (°C), the measured pose ``x, y, z`` (m) and
``qx, qy, qz, qw``, optional simulator-only ``true_*``. A thermometer's channel ``<name>``
and its column ``temp_<name>`` are told apart by one rule everywhere: :func:`temperature_column`,
:func:`temperature_name`, :func:`temperature_columns`. Metadata travels in
``<dataset>.meta.json`` (both formats) and, for Parquet, in the file's key-value metadata.
Writes are atomic: a temporary file in the same folder, then a rename.
"""

from __future__ import annotations

import glob
import json
import os
import tempfile
from collections.abc import Callable, Iterable
from dataclasses import asdict, dataclass, field
from pathlib import Path

import numpy as np
import pandas as pd
import pyarrow as pa
import pyarrow.parquet as pq

from kinematics.errors import DatasetError
from kinematics.transforms import invert, transform_from_xyz_quat

POSE_COLUMNS = ("x", "y", "z", "qx", "qy", "qz", "qw")
FRAMES = ("base", "tracker")
META_KEY = b"robocal.meta"
#: The prefix of a temperature column: channel ``ambient`` is column ``temp_ambient``.
TEMPERATURE_PREFIX = "temp_"


@dataclass(frozen=True, kw_only=True)
class DatasetMeta:
    """What a dataset says about itself: robot, pose frame, cell frames, noise (SI units)."""

    robot: str
    frame: str = "base"
    T_W_0: list[list[float]] | None = None
    T_6_S: list[list[float]] | None = None
    noise_floor_m: float | None = None
    extra: dict = field(default_factory=dict)

    def __post_init__(self) -> None:
        if self.frame not in FRAMES:
            raise DatasetError(f"meta.frame must be one of {FRAMES}, got {self.frame!r}")
        for key in ("T_W_0", "T_6_S"):
            value = getattr(self, key)
            if value is not None and np.asarray(value, dtype=float).shape != (4, 4):
                raise DatasetError(f"meta.{key} must be a 4x4 matrix")


@dataclass
class Dataset:
    """A table of measured points and its metadata."""

    table: pd.DataFrame
    meta: DatasetMeta

    def __len__(self) -> int:
        return len(self.table)

    @property
    def n_joints(self) -> int:
        return len(joint_columns(self.table))

    def q(self) -> np.ndarray:
        """Controller joint angles ``(N, n)``, rad."""
        return self.table[joint_columns(self.table)].to_numpy(float)

    def deflection(self) -> np.ndarray | None:
        """Elastic deflections ``qs - q`` ``(N, n)`` rad, or None without secondary encoders."""
        cols = secondary_columns(self.table)
        if not cols:
            return None
        return self.table[cols].to_numpy(float) - self.q()

    def temperatures(self) -> np.ndarray | None:
        """Temperatures ``(N, k)`` °C in column order, or None."""
        cols = temperature_columns(self.table)
        return self.table[cols].to_numpy(float) if cols else None

    def measured_poses(self) -> np.ndarray:
        """Measured poses ``(N, 4, 4)`` in the frame the metadata names."""
        t = self.table
        return transform_from_xyz_quat(
            t[["x", "y", "z"]].to_numpy(float), t[["qx", "qy", "qz", "qw"]].to_numpy(float)
        )

    def measured_poses_base(self) -> np.ndarray:
        """Measured probe poses ``T_0_S`` ``(N, 4, 4)`` in the robot base frame."""
        return poses_in_base(self.measured_poses(), self.meta.frame, self.meta.T_W_0)

    def subset(self, index: np.ndarray) -> Dataset:
        """The rows at ``index`` (positions), same metadata."""
        return Dataset(self.table.iloc[np.asarray(index)].reset_index(drop=True), self.meta)


def joint_columns(table: pd.DataFrame) -> list[str]:
    return _numbered(table, "q")


def secondary_columns(table: pd.DataFrame) -> list[str]:
    return _numbered(table, "qs")


def temperature_column(name: str) -> str:
    """The column of a thermometer channel: ``temp_<name>`` (a column name stays as it is)."""
    return name if name.startswith(TEMPERATURE_PREFIX) else TEMPERATURE_PREFIX + name


def temperature_name(column: str) -> str:
    """The channel name of a temperature column: ``temp_<name>`` -> ``<name>``."""
    return column.removeprefix(TEMPERATURE_PREFIX)


def temperature_columns(columns: Iterable[str] | pd.DataFrame) -> list[str]:
    """The temperature columns among ``columns`` (a table's, or feature names), in order."""
    return [c for c in columns if c.startswith(TEMPERATURE_PREFIX)]


def poses_in_base(T: np.ndarray, frame: str, T_W_0: np.ndarray | list | None) -> np.ndarray:
    """Poses ``(N, 4, 4)`` measured in ``frame`` (``base`` or ``tracker``) in the robot base
    frame, which a tracker-frame pose needs ``T_W_0`` for."""
    if frame == "base":
        return T
    if T_W_0 is None:
        raise DatasetError("dataset poses are in the tracker frame but meta.T_W_0 is unknown")
    return invert(np.asarray(T_W_0, dtype=float))[None] @ T


def _numbered(table: pd.DataFrame, prefix: str) -> list[str]:
    cols = []
    while f"{prefix}{len(cols) + 1}" in table.columns:
        cols.append(f"{prefix}{len(cols) + 1}")
    return cols


def validate(ds: Dataset, source: str = "dataset", limits_rad: np.ndarray | None = None) -> None:
    """Raise :class:`DatasetError` naming the file, row and field of the first problem."""
    t = ds.table
    missing = [c for c in ("t", *POSE_COLUMNS) if c not in t.columns]
    qcols = joint_columns(t)
    if not qcols:
        missing.append("q1")
    if missing:
        raise DatasetError(f"{source}: missing column(s) {', '.join(missing)}")
    if t.empty:
        raise DatasetError(f"{source}: no rows")
    sec = secondary_columns(t)
    if sec and len(sec) != len(qcols):
        raise DatasetError(f"{source}: {len(sec)} secondary columns qs* for {len(qcols)} joints")
    numeric = ["t", *qcols, *sec, *temperature_columns(t), *POSE_COLUMNS]
    for col in numeric:
        values = pd.to_numeric(t[col], errors="coerce").to_numpy(float)
        bad = np.flatnonzero(~np.isfinite(values))
        if bad.size:
            raise DatasetError(
                f"{source}: row {bad[0]}, column {col!r}: value is not a finite number"
            )
    norms = np.linalg.norm(t[["qx", "qy", "qz", "qw"]].to_numpy(float), axis=1)
    bad = np.flatnonzero(np.abs(norms - 1.0) > 1e-3)
    if bad.size:
        raise DatasetError(
            f"{source}: row {bad[0]}: quaternion norm {norms[bad[0]]:.4f}, expected 1"
        )
    if limits_rad is not None:
        check_joint_limits(ds, source, limits_rad)


def check_joint_limits(ds: Dataset, source: str, limits_rad: np.ndarray) -> None:
    """Raise :class:`DatasetError` naming the first row and joint outside ``limits_rad``
    (rad, (n, 2)): the part of :func:`validate` that needs the robot's description."""
    qcols = joint_columns(ds.table)
    q = ds.table[qcols].to_numpy(float)
    lo, hi = limits_rad[: len(qcols), 0], limits_rad[: len(qcols), 1]
    out = np.argwhere((q < lo - 1e-9) | (q > hi + 1e-9))
    if out.size:
        r, c = out[0]
        raise DatasetError(
            f"{source}: row {r}, column {qcols[c]!r}: {np.rad2deg(q[r, c]):.3f} deg outside "
            f"the joint limits [{np.rad2deg(lo[c]):.1f}, {np.rad2deg(hi[c]):.1f}] deg"
        )


def meta_path(path: str | Path) -> Path:
    """The sidecar ``<dataset>.meta.json`` of a dataset file."""
    path = Path(path)
    return (
        path.with_name(path.name + ".meta.json")
        if path.suffix == ""
        else path.with_suffix(".meta.json")
    )


def write_dataset(ds: Dataset, path: str | Path) -> Path:
    """Write ``ds`` to ``.parquet`` or ``.csv`` plus the meta sidecar, atomically."""
    path = Path(path)
    if path.suffix not in (".parquet", ".csv"):
        raise DatasetError(f"{path}: dataset files end in .parquet or .csv, got {path.suffix!r}")
    meta_json = json.dumps(asdict(ds.meta), indent=2, sort_keys=True)
    if path.suffix == ".parquet":
        table = pa.Table.from_pandas(ds.table, preserve_index=False)
        table = table.replace_schema_metadata(
            {**(table.schema.metadata or {}), META_KEY: meta_json}
        )
        atomic_write(path, lambda tmp: pq.write_table(table, tmp))
    else:
        atomic_write(path, lambda tmp: ds.table.to_csv(tmp, index=False, float_format="%.17g"))
    atomic_write(meta_path(path), lambda tmp: Path(tmp).write_text(meta_json + "\n"))
    return path


def read_dataset(path: str | Path, limits_rad: np.ndarray | None = None) -> Dataset:
    """Read and validate a dataset (``.parquet`` or ``.csv`` with its sidecar)."""
    path = Path(path)
    if not path.exists():
        raise DatasetError(f"{path}: no such dataset file")
    raw_meta = None
    if meta_path(path).exists():
        raw_meta = meta_path(path).read_text()
    try:
        if path.suffix == ".parquet":
            table = pq.read_table(path)
            raw_meta = raw_meta or (table.schema.metadata or {}).get(META_KEY, b"").decode() or None
            frame = table.to_pandas()
        elif path.suffix == ".csv":
            frame = pd.read_csv(path)
        else:
            raise DatasetError(
                f"{path}: dataset files end in .parquet or .csv, got {path.suffix!r}"
            )
    except (pa.ArrowInvalid, pd.errors.ParserError, UnicodeDecodeError) as exc:
        raise DatasetError(f"{path}: unreadable: {str(exc).splitlines()[0]}") from None
    if raw_meta is None:
        raise DatasetError(f"{path}: no metadata (expected {meta_path(path).name})")
    try:
        meta = DatasetMeta(**json.loads(raw_meta))
    except (TypeError, json.JSONDecodeError) as exc:
        raise DatasetError(f"{path}: bad metadata: {exc}") from None
    ds = Dataset(frame, meta)
    validate(ds, str(path), limits_rad)
    return ds


#: :func:`atomic_write`'s temporary file beside ``name``: ``.<name>.<random>.tmp``.
_TMP_PREFIX, _TMP_SUFFIX = ".{name}.", ".tmp"


def atomic_write(path: str | Path, write: Callable[[str], object]) -> Path:
    """Call ``write(tmp)`` on a temporary file beside ``path``, then rename it over ``path``:
    nothing half-written remains, the file gets the user's umask (not mkstemp's 0600), and an
    OSError (a full disk's write names no file) is raised again naming ``path``."""
    path = Path(path)
    tmp = None
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        prefix = _TMP_PREFIX.format(name=path.name)
        fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=prefix, suffix=_TMP_SUFFIX)
        os.close(fd)
        write(tmp)
        os.chmod(tmp, 0o666 & ~current_umask())
        os.replace(tmp, path)
    except BaseException as exc:
        if tmp is not None:
            Path(tmp).unlink(missing_ok=True)
        if isinstance(exc, OSError) and exc.errno is not None:
            raise OSError(exc.errno, os.strerror(exc.errno), str(path)) from None
        if isinstance(exc, OSError):  # pyarrow's errors carry a message only
            raise OSError(f"{path}: {str(exc).splitlines()[0] if str(exc) else exc!r}") from None
        raise
    return path


def remove_stale_temporaries(path: str | Path) -> int:
    """Delete what :func:`atomic_write` left beside ``path`` when its process was killed
    between writing and renaming (``kill -9``, power loss); the count. Only for a file one
    process owns, at its start (a checkpoint)."""
    path = Path(path)
    prefix = _TMP_PREFIX.format(name=glob.escape(path.name))
    stale = list(path.parent.glob(f"{prefix}*{_TMP_SUFFIX}"))
    for tmp in stale:
        tmp.unlink(missing_ok=True)
    return len(stale)


def current_umask() -> int:
    """The process umask, read without setting it (Linux ``/proc/self/status``; elsewhere set
    and restored at once)."""
    try:
        for line in Path("/proc/self/status").read_text().splitlines():
            if line.startswith("Umask:"):
                return int(line.split()[1], 8)
    except (OSError, ValueError, IndexError):
        pass
    mask = os.umask(0o022)
    os.umask(mask)
    return mask
