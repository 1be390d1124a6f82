"""Network inputs from raw features: the kinematic encoding (default) or plain min-max.

``"kinematic"`` gives the network what the nominal model already knows, all on fixed scales:

- each joint as ``sin`` and ``cos`` of its DH variable (angles wrap; a ±360° wrist is one
  circle, not a line that min-max squeezes twice around);
- the nominal sensor pose: position divided by the arm's reach, rotation matrix entries;
- with secondary encoders, the first-order sensor displacement the measured deflections cause,
  ``J(q) dtheta`` (position in units of reach × declared deflection range, rotation in units of
  the declared range) — how a joint deflection moves the tool depends on the whole pose;
- temperatures min-max over their declared range, as before.

``"minmax"`` maps every raw feature to ``[-1, 1]`` over its declared range (DESIGN.md as
written). On the simulated paper campaign the kinematic encoding cuts the batch model's mean
test error from 0.40 to about 0.05 mm (BENCHMARKS.md, "Learner").

>>> from kinematics.description import load_description
>>> from learner.features import feature_spec
>>> spec = feature_spec(load_description("ur10"), n_temperatures=1, has_secondary=True)
>>> n_inputs(spec, "kinematic"), n_inputs(spec, "minmax")
(31, 13)
>>> input_encoder(spec, "kinematic")(np.zeros((1, 13))).shape
(1, 31)
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from kinematics.description import RobotDescription
from kinematics.effects import dh_table, sensor_jacobians
from kinematics.errors import ConfigError
from learner.config import ENCODINGS
from learner.features import FeatureSpec

#: sin, cos per joint; position (3) and rotation matrix (9) of the sensor.
_POSE_INPUTS = 12


def reach_m(desc: RobotDescription) -> float:
    """An upper bound on the sensor's distance from the base origin (m): links plus tool."""
    links = sum(np.hypot(j.a_m, j.d_m) for j in desc.joints)
    return float(links + np.linalg.norm(desc.tool[:3, 3]))


def n_inputs(spec: FeatureSpec, encoding: str) -> int:
    """How many network inputs ``encode`` makes from ``spec``'s raw features."""
    if encoding == "minmax":
        return spec.n_features
    n_q, n_dtheta, n_other = _counts(spec, encoding)
    return 2 * n_q + _POSE_INPUTS + (6 if n_dtheta else 0) + n_other


def input_encoder(spec: FeatureSpec, encoding: str) -> Callable[[np.ndarray], np.ndarray]:
    """The function from raw SI features ``(N, F)`` in ``spec.names`` order to network inputs
    ``(N, n_inputs)``; what depends only on the description is computed once, here."""
    if encoding == "minmax":
        return spec.scale
    n_q, n_dtheta, _ = _counts(spec, encoding)
    desc = spec.description
    offsets = dh_table(desc)[:, 4]
    reach = reach_m(desc)
    poses_and_jacobians = sensor_jacobians(desc)
    moved_scale = np.repeat(
        [reach * desc.sensors.deflection_max_rad, desc.sensors.deflection_max_rad], 3
    )

    def encode(X: np.ndarray) -> np.ndarray:
        scaled = spec.scale(X)  # checks the shape
        X = np.asarray(X, dtype=float)
        q = X[:, :n_q]
        q_dh = desc.to_dh(q) + offsets
        T, J = poses_and_jacobians(q)
        parts = [np.sin(q_dh), np.cos(q_dh), T[:, :3, 3] / reach, T[:, :3, :3].reshape(-1, 9)]
        if n_dtheta:
            dtheta = X[:, n_q : 2 * n_q]
            parts.append(np.einsum("nij,nj->ni", J, dtheta) / moved_scale)
        parts.append(scaled[:, n_q + n_dtheta :])
        return np.concatenate(parts, axis=1)

    return encode


def _counts(spec: FeatureSpec, encoding: str) -> tuple[int, int, int]:
    """Joints, deflections and other features of a spec the kinematic encoding can read."""
    if encoding not in ENCODINGS:
        raise ConfigError(f"encoding must be one of {ENCODINGS}, got {encoding!r}")
    desc = spec.description
    if desc is None:
        raise ConfigError("the kinematic encoding needs the robot description in the feature spec")
    n = desc.n_joints
    joints = tuple(f"q{i}" for i in range(1, n + 1))
    if spec.names[:n] != joints:
        raise ConfigError(f"the kinematic encoding needs features {joints} first, got {spec.names}")
    n_dtheta = n if spec.names[n : 2 * n] == tuple(f"dtheta{i}" for i in range(1, n + 1)) else 0
    return n, n_dtheta, spec.n_features - n - n_dtheta
