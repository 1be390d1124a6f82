"""Physical effects of the vocabulary in DESIGN.md, each a parameterised model addition."""

from kinematics.effects._base import (
    DH_FIELDS,
    Conditions,
    Effect,
    Perturbation,
    dh_poses,
    dh_table,
    perturbed_poses,
)

__all__ = [
    "DH_FIELDS",
    "Conditions",
    "Effect",
    "Perturbation",
    "dh_poses",
    "dh_table",
    "perturbed_poses",
]
