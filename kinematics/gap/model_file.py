"""The updated model the workflow writes and the simulator can run: one TOML file.

It is a robot description (:func:`description_to_toml`, read back by ``load_description``,
which ignores the extra tables) with the identified base frame and one ``[[effect]]`` table
per identified effect that is not folded into the description::

    [cell]
    T_W_0 = [[1.0, 0.0, 0.0, 0.0], ...]

    [[effect]]
    name = "joint_compliance"
    options = { balancer = [0.0, 0.92, 0.0, 0.0, 0.0, 0.0] }
    parameters = { c1_rad_per_Nm = 3.1e-08, ... }   # every parameter, SI
    std = { c1_rad_per_Nm = 2e-10, ... }            # the estimated ones

``load_model_file`` returns the description, ``T_W_0`` and ``[(effect, params), ...]`` ready
for :func:`kinematics.effects.perturbed_poses`.
"""

from __future__ import annotations

import tomllib
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from kinematics.description import RobotDescription, description_from_dict, description_to_toml
from kinematics.effects import Effect
from kinematics.errors import DescriptionError, RobocalError
from kinematics.gap.candidates import make_effect


@dataclass(frozen=True, kw_only=True)
class EffectEntry:
    """One identified effect: name, constructor options, all parameters, known std (SI)."""

    name: str
    options: dict
    parameters: dict[str, float]
    std: dict[str, float]
    identified: bool = True


@dataclass(frozen=True, kw_only=True)
class ModelFile:
    """A description, the base frame ``T_W_0`` and the effects added to it."""

    description: RobotDescription
    T_W_0: np.ndarray
    effects: tuple[EffectEntry, ...]

    def blocks(self) -> list[tuple[Effect, np.ndarray]]:
        """``[(effect, params), ...]`` in each effect's parameter order."""
        out = []
        for e in self.effects:
            effect = make_effect(e.name, e.options)
            names = effect.parameter_names(self.description)
            missing = [n for n in names if n not in e.parameters]
            if missing:
                raise DescriptionError(f"effect {e.name!r}: missing parameter(s) {missing}")
            out.append((effect, np.array([e.parameters[n] for n in names])))
        return out


def _value(v) -> str:
    if isinstance(v, str):
        return f'"{v}"'
    if isinstance(v, list | tuple):
        return "[" + ", ".join(_value(x) for x in v) + "]"
    if isinstance(v, bool):
        return "true" if v else "false"
    return repr(float(v)) if isinstance(v, float) else repr(v)


def _inline(d: dict) -> str:
    return "{ " + ", ".join(f"{_key(k)} = {_value(v)}" for k, v in d.items()) + " }" if d else "{}"


def _key(name: str) -> str:
    """A TOML key: bare when it can be (letters, digits, ``_``, ``-``), else quoted."""
    if name and all(c.isascii() and (c.isalnum() or c in "_-") for c in name):
        return name
    return '"' + name.replace("\\", "\\\\").replace('"', '\\"') + '"'


def model_to_toml(model: ModelFile) -> str:
    """The TOML text of ``model`` (see the module docstring)."""
    lines = [description_to_toml(model.description), "[cell]"]
    lines.append("T_W_0 = " + _value([[float(x) for x in row] for row in model.T_W_0]))
    for e in model.effects:
        lines += [
            "",
            "[[effect]]",
            f'name = "{e.name}"',
            f"options = {_inline(e.options)}",
            *([] if e.identified else ["identified = false"]),
            f"parameters = {_inline({k: float(v) for k, v in e.parameters.items()})}",
            f"std = {_inline({k: float(v) for k, v in e.std.items()})}",
        ]
    return "\n".join(lines) + "\n"


def load_model_file(path: str | Path) -> ModelFile:
    """Read a model file written by :func:`model_to_toml`; bad content -> DescriptionError."""
    path = Path(path)
    try:
        raw = tomllib.loads(path.read_text())
    except (OSError, tomllib.TOMLDecodeError) as exc:
        raise DescriptionError(f"{path}: cannot read model file: {exc}") from None
    try:
        desc = description_from_dict(raw)
        T_W_0 = np.asarray(raw.get("cell", {}).get("T_W_0", np.eye(4).tolist()), dtype=float)
        if T_W_0.shape != (4, 4):
            raise DescriptionError(f"cell.T_W_0 must be 4x4, got shape {T_W_0.shape}")
        effects = tuple(
            EffectEntry(
                name=str(row["name"]),
                options=dict(row.get("options", {})),
                parameters={k: float(v) for k, v in row.get("parameters", {}).items()},
                std={k: float(v) for k, v in row.get("std", {}).items()},
                identified=bool(row.get("identified", True)),
            )
            for row in raw.get("effect", [])
        )
        model = ModelFile(description=desc, T_W_0=T_W_0, effects=effects)
        model.blocks()
    except KeyError as exc:
        raise DescriptionError(f"{path}: effect table without {exc}") from None
    except RobocalError as exc:
        raise DescriptionError(f"{path}: {exc}") from None
    return model
