"""When and from which points a continual learner re-identifies its physics base.

A learner identifies its base (``auto`` or ``geometric``, :mod:`learner.base`) from its first
``init`` points and would keep it for good; batch training identifies it from every training
point. On the simulated paper campaign the first 50 points leave the base 0.858 mm off on the
test points against 0.743 mm from all 2,704 (200 points spread over the stream: 0.745 mm), a
difference the residual network must then learn. So the learner identifies it again from
points spread over its replay memory each time the versions double (8, 16, 32, ...), and an
``auto`` base the first points left on the nominal every :data:`LATE_BASE_EVERY` versions until
identified. The caller retrains on the new base and keeps it only where the held-out error falls.

>>> due(16, "identified"), due(24, "identified"), due(20, "nominal"), due(21, "nominal")
(True, False, True, False)
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from learner.base import IDENTIFY_POINTS, PhysicsBase, identify_base
from learner.features import FeatureSpec

#: Versions between tries to identify an ``auto`` base the first points left on the nominal.
LATE_BASE_EVERY = 10
#: The first version at which an identified base is identified again (then at its doubles).
FIRST_REIDENTIFY = 8


def status(base: PhysicsBase) -> str:
    """``identified`` (an ``auto``/``geometric`` base the learner identified), ``nominal`` (an
    ``auto`` base left on the nominal) or ``fixed`` (nominal, a file, carried frames)."""
    if base.kind not in ("auto", "geometric"):
        return "fixed"
    return "nominal" if base.note.startswith("nominal:") else "identified"


def due(version: int, state: str) -> bool:
    """Whether the base in ``state`` (:func:`status`) is identified again at ``version``."""
    if state == "nominal":
        return version > 0 and version % LATE_BASE_EVERY == 0
    is_power = version & (version - 1) == 0
    return state == "identified" and version >= FIRST_REIDENTIFY and is_power


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
    return None if new.note.startswith("nominal:") else replace(new, kind=base.kind)
