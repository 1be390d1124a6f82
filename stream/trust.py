"""Which model snapshots a consumer adopts (the compensation service, the dashboard).

A snapshot belongs to the cell when its header names the cell's robot (the config's key name or
the description's name), its description is the cell's (:func:`description_hash` over name,
coupling and every joint's DH parameters and limits; the tool is left out, since frames are
re-identified per cell), its feature names are ones a learner of this robot forms (``q1..qn``,
all or none of ``dtheta1..n``, ``temp_<name>``) and stay those of the first model adopted, and
its version is plausible: above the adopted one by at most ``max_version_jump`` and no more than
the points it has seen (+1). A version at or below the adopted one is ``model_old``; when
``confirm_models`` such models in a row agree (rising versions, all belonging), the learner has
started again (a lost state directory) or the adopted one was forged, and they are adopted.
The first wall; the signing or ACL of issue 18 is the second.

>>> from kinematics.description import load_description
>>> len(description_hash(load_description("ur10")))
16
"""

from __future__ import annotations

import hashlib
import json
from dataclasses import dataclass

from kinematics.dataset import temperature_columns, temperature_name
from kinematics.description import RobotDescription
from kinematics.errors import ConfigError
from learner.model import ErrorModel
from learner.snapshot import snapshot_from_bytes
from wire import ModelHeader, RejectedMessageError, decode_model


@dataclass(frozen=True, kw_only=True)
class ModelTrustConfig:
    """How far a model's version may jump past the adopted one, and how many lower-versioned
    models in a row replace it."""

    max_version_jump: int = 100
    confirm_models: int = 3

    def __post_init__(self) -> None:
        for name in ("max_version_jump", "confirm_models"):
            value = getattr(self, name)
            if not (isinstance(value, int) and value >= 1):
                raise ConfigError(f"models.{name} must be an int >= 1, got {value!r}")


def description_hash(desc: RobotDescription) -> str:
    """16 hex digits identifying a robot's kinematics (name, coupling, DH, limits; no tool)."""
    joints = [
        [round(float(getattr(j, k)), 9) for k in ("a_m", "d_m", "alpha_deg", "beta_deg")]
        + [round(float(getattr(j, k)), 9) for k in ("offset_deg", "lower_deg", "upper_deg")]
        for j in desc.joints
    ]
    text = json.dumps([desc.name, desc.coupling, joints], separators=(",", ":"))
    return hashlib.sha256(text.encode()).hexdigest()[:16]


def check_feature_names(names: tuple[str, ...], n_joints: int) -> None:
    """RejectedMessageError (``model_foreign``) unless a learner of an ``n_joints`` robot
    could have formed ``names``."""
    q = [f"q{i}" for i in range(1, n_joints + 1)]
    dtheta = [f"dtheta{i}" for i in range(1, n_joints + 1)]
    rest = list(names[n_joints:])
    if list(names[:n_joints]) != q:
        raise RejectedMessageError("model_foreign", f"features {names[:n_joints]} are not {q}")
    if rest[:n_joints] == dtheta:
        rest = rest[n_joints:]
    bad = [n for n in rest if not (temperature_columns([n]) and temperature_name(n))]
    if bad or len(set(rest)) != len(rest):
        raise RejectedMessageError("model_foreign", f"features {bad or rest} are not thermometers")


class ModelGate:
    """Decides, snapshot by snapshot, whether a consumer adopts it (see the module doc)."""

    def __init__(
        self, robot: str, desc: RobotDescription, cfg: ModelTrustConfig | None = None
    ) -> None:
        self.names = {robot, desc.name}
        self.desc, self.hash = desc, description_hash(desc)
        self.cfg = cfg or ModelTrustConfig()
        self.version = -1
        self.features: tuple[str, ...] | None = None
        self._lower: list[int] = []

    def admit(self, payload: bytes) -> tuple[ModelHeader, ErrorModel]:
        """The header and model of a snapshot to adopt now; RejectedMessageError otherwise
        (``model_foreign``, ``model_version``, ``model_old``, ``snapshot``, ...)."""
        header, snap = decode_model(payload)
        if header.robot not in self.names:
            raise RejectedMessageError(
                "model_foreign", f"model of robot {header.robot!r}, this cell runs {self.names}"
            )
        v = header.model_version
        if v > header.n_seen + 1:
            raise RejectedMessageError(
                "model_version", f"version {v} after only {header.n_seen} points"
            )
        old = v <= self.version
        if not old and self.version >= 0 and v > self.version + self.cfg.max_version_jump:
            raise RejectedMessageError(
                "model_version",
                f"version {v} jumps more than {self.cfg.max_version_jump} past {self.version}",
            )
        if old and not self._confirms_restart(v):
            raise RejectedMessageError("model_old", f"version {v} <= adopted {self.version}")
        model = self._load(snap)
        if old:
            self._lower.clear()
        self.version, self.features = v, tuple(model.feature_names)
        return header, model

    def _confirms_restart(self, v: int) -> bool:
        """Whether ``v`` is the ``confirm_models``-th rising lower version in a row."""
        if self._lower and v <= self._lower[-1]:
            self._lower.clear()
        self._lower.append(v)
        return len(self._lower) >= self.cfg.confirm_models

    def _load(self, snap: bytes) -> ErrorModel:
        try:
            model = snapshot_from_bytes(snap)
        except Exception as exc:  # any corrupt snapshot: named, never raised through
            raise RejectedMessageError("snapshot", f"{type(exc).__name__}: {exc}"[:200]) from None
        desc = model.spec.description
        if desc is None or desc.name != self.desc.name or description_hash(desc) != self.hash:
            got = None if desc is None else f"{desc.name} {description_hash(desc)}"
            raise RejectedMessageError(
                "model_foreign", f"description {got}, the cell's is {self.desc.name} {self.hash}"
            )
        names = tuple(model.feature_names)
        check_feature_names(names, self.desc.n_joints)
        if self.features is not None and names != self.features:
            raise RejectedMessageError(
                "model_foreign", f"features {names} differ from the adopted {self.features}"
            )
        return model
