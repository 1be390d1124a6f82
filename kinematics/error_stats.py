"""One record of error statistics: position error (mm) and orientation error (arcmin) of ``n``
points, with the same fields and conventions wherever robocal summarises errors (uncalibrated
accuracy, calibration residuals, frame fits, gap regions, a model's test error).

>>> s = ErrorStats.of(np.array([1.0, 2.0, 3.0]))
>>> s.n, s.mean_mm, s.std_mm, s.max_mm, bool(np.isnan(s.mean_arcmin))
(3, 2.0, 1.0, 3.0, True)
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import ClassVar, Self

import numpy as np


@dataclass(frozen=True, kw_only=True)
class ErrorStats:
    """Mean, standard deviation, RMS, 95th percentile and max of per-point position errors (mm);
    mean, RMS and max of orientation errors (arcmin, NaN when there are none).

    ``std_mm`` is the sample standard deviation (``ddof=1``, divisor ``n - 1``; 0 for one
    point): the points are a sample of the workspace, and the figure estimates the spread of the
    robot's error over it, as ISO 9283's S_l and the published std of the paper campaign
    (bench/sim_campaign.py) do. Records with more fields subclass this one; :attr:`KEYS` are
    the keys, in order, that their :meth:`to_dict` (JSON) writes.
    """

    n: int
    mean_mm: float
    std_mm: float
    rms_mm: float
    p95_mm: float
    max_mm: float
    mean_arcmin: float
    rms_arcmin: float
    max_arcmin: float

    KEYS: ClassVar[tuple[str, ...]] = (
        "n",
        "mean_mm",
        "std_mm",
        "rms_mm",
        "p95_mm",
        "max_mm",
        "mean_arcmin",
        "rms_arcmin",
        "max_arcmin",
    )

    @classmethod
    def of(cls, mm: np.ndarray, arcmin: np.ndarray | None = None, **extra: object) -> Self:
        """The statistics of position errors ``mm`` (N,) and orientation errors ``arcmin`` (N,)
        (None: NaN); ``extra`` fills a subclass's other fields."""
        mm = np.asarray(mm, dtype=float)
        am = np.full(1, np.nan) if arcmin is None else np.asarray(arcmin, dtype=float)
        return cls(
            n=int(mm.size),
            mean_mm=float(mm.mean()),
            std_mm=float(mm.std(ddof=1)) if mm.size > 1 else 0.0,
            rms_mm=float(np.sqrt(np.mean(mm**2))),
            p95_mm=float(np.percentile(mm, 95)),
            max_mm=float(mm.max()),
            mean_arcmin=float(am.mean()),
            rms_arcmin=float(np.sqrt(np.mean(am**2))),
            max_arcmin=float(am.max()),
            **extra,
        )

    def to_dict(self) -> dict:
        """The record's :attr:`KEYS` and their values (the JSON of the CLI and of snapshots)."""
        return {k: getattr(self, k) for k in self.KEYS}
