"""Physical effects of the vocabulary in DESIGN.md, each a parameterised model addition.

``EFFECTS`` maps each vocabulary name to its class (constructible without arguments).

>>> sorted(EFFECTS)[:3]
['backlash', 'base_frame', 'gear_periodic']
"""

from kinematics.effects._base import (
    DH_FIELDS,
    Conditions,
    Effect,
    Perturbation,
    Restricted,
    coupling_matrix,
    ctrl_to_dh_delta,
    dh_frames,
    dh_poses,
    dh_table,
    dh_to_ctrl_delta,
    frame_correction,
    perturbed_poses,
    sensor_jacobians,
)
from kinematics.effects.backlash import Backlash
from kinematics.effects.frames import BaseFrame, ToolFrame
from kinematics.effects.gear_periodic import GearPeriodic
from kinematics.effects.geometric import Geometric
from kinematics.effects.joint_compliance import JointCompliance, compliance_deflection
from kinematics.effects.thermal_expansion import (
    REFERENCE_SENSORS,
    STRUCTURE_SENSORS,
    ThermalExpansion,
)
from kinematics.effects.tracker_drift import TrackerDrift

EFFECTS: dict[str, type[Effect]] = {
    cls.name: cls
    for cls in (
        Geometric,
        JointCompliance,
        ThermalExpansion,
        Backlash,
        GearPeriodic,
        TrackerDrift,
        BaseFrame,
        ToolFrame,
    )
}

__all__ = [
    "DH_FIELDS",
    "EFFECTS",
    "REFERENCE_SENSORS",
    "STRUCTURE_SENSORS",
    "Backlash",
    "BaseFrame",
    "Conditions",
    "Effect",
    "GearPeriodic",
    "Geometric",
    "JointCompliance",
    "Perturbation",
    "Restricted",
    "ThermalExpansion",
    "ToolFrame",
    "TrackerDrift",
    "compliance_deflection",
    "coupling_matrix",
    "ctrl_to_dh_delta",
    "dh_frames",
    "dh_poses",
    "dh_table",
    "dh_to_ctrl_delta",
    "frame_correction",
    "perturbed_poses",
    "sensor_jacobians",
]
