"""When and from which points a continual learner identifies its physics base again.

A learner identifies its base (``auto`` or ``geometric``, :mod:`learner.base`) from its first
``init`` points; batch training identifies it from every training point. An identified base is
identified again from every trained point each time they double (:func:`doubled`,
:func:`refined_base`), while the replay memory still holds them all, and the network goes on
learning on it: the paper campaign's continual model at N_m 2,000 came from 0.0274 mm (base of
the first 50 points) to 0.0253 mm, its batch model's 0.0255 mm (three seeds), UR10 Series A's
from 0.237 to 0.213 mm and B's (first 50 points: condition 54.6) from 0.386 to 0.368 mm
(BENCHMARKS.md). An ``auto`` base the first
points left on the nominal is identified from points spread over the replay memory every
:data:`LATE_BASE_EVERY` versions until it is; the caller retrains on it and keeps it only
where the held-out error falls.

A model file's base that leaves effects out (``robocal gap`` named tracker drift or backlash,
:func:`learner.base.refit_base`) is fitted again in the same way: on the first points and as
they double, where they identify every parameter it fits (condition number at most
:data:`~learner.base.AUTO_MAX_CONDITION`). On a random arm with tracker drift, a stream of
2,250 points on the gap model file of the 1,500 before ended 0.093 mm off on the file as it
was fitted again, 0.135 mm on it as filed; on UR10 Series A the file's gear correction is
never identified that well from a stream's points (condition 1.6e3-5.0e4: fitted again on the
first 100, the base was 1.66 mm off against 0.46 mm as filed), so it stays as filed.

>>> scheduled(20, "nominal"), scheduled(21, "nominal"), scheduled(20, "identified")
(True, False, False)
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from kinematics.errors import IdentifiabilityError
from learner.base import (
    AUTO_MAX_CONDITION,
    IDENTIFY_POINTS,
    PhysicsBase,
    identify_base,
    refit_base,
)
from learner.features import FeatureSpec
from learner.refresh import grew

#: Versions between tries to identify an ``auto`` base the first points left on the nominal.
LATE_BASE_EVERY = 10
#: The :func:`status` of a base fitted again as the trained points double (:func:`refined_base`).
REFINED = ("identified", "refitted")


def status(base: PhysicsBase) -> str:
    """``identified`` (an ``auto``/``geometric`` base the learner identified), ``nominal`` (an
    ``auto`` base left on the nominal), ``refitted`` (a model file's base that leaves effects
    out, its other parameters fitted to the points, :func:`learner.base.refit_base`) or
    ``fixed`` (nominal, any other file, carried frames)."""
    if base.left_out:
        return "refitted"
    if base.kind not in ("auto", "geometric"):
        return "fixed"
    return "nominal" if base.on_nominal else "identified"


def due(version: int, base: PhysicsBase) -> bool:
    """Whether an ``auto`` base left on the nominal is identified again at ``version``."""
    return scheduled(version, status(base))


def scheduled(version: int, state: str) -> bool:
    """Whether a base in ``state`` (:func:`status`) is identified again at ``version``."""
    return state == "nominal" and version > 0 and version % LATE_BASE_EVERY == 0


def memory_base(
    base: PhysicsBase, spec: FeatureSpec, X: np.ndarray, Y: np.ndarray
) -> PhysicsBase | None:
    """The base identified again from :data:`IDENTIFY_POINTS` points spread over ``X, Y`` (the
    replay memory), of ``base``'s kind; ``None`` when they are too few or identify it only
    ill-conditioned (:data:`learner.base.AUTO_MAX_CONDITION`)."""
    if len(X) < IDENTIFY_POINTS:
        return None
    spread = np.linspace(0, len(X) - 1, IDENTIFY_POINTS).astype(int)
    new = identify_base("auto", spec, X[spread], Y[spread])
    return None if new.on_nominal else replace(new, kind=base.kind)


def doubled(before: int, after: int, init: int) -> bool:
    """Whether the trained points grew past ``init`` times a power of two (``before`` ->
    ``after`` points): when an identified base is refined (:func:`refined_base`).

    >>> [n for n in range(50, 500, 90) if doubled(n, n + 90, 50)]
    [50, 140, 320]
    """
    return grew(before, after, init, 2.0)


def refined_base(
    base: PhysicsBase, spec: FeatureSpec, X: np.ndarray, Y: np.ndarray
) -> PhysicsBase | None:
    """``base`` (an identified or refitted one, :func:`status`) identified or fitted again
    from every trained point ``X, Y`` so far; None when they identify it only ill-conditioned.
    The network goes on learning on it."""
    try:
        if status(base) == "refitted":
            new = refit_base(base, spec, X, Y, max_condition=AUTO_MAX_CONDITION)
        else:
            new = replace(identify_base("geometric", spec, X, Y), kind=base.kind)
    except IdentifiabilityError:
        return None
    return None if new.condition > AUTO_MAX_CONDITION else new
