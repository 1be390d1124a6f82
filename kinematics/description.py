"""Robot descriptions: DH + Hayati parameters, joint limits, J2/J3 coupling, tool, inertia.

A description is loaded once from TOML (DESIGN.md, "Robot description") and passed down as a
frozen value. Per joint ``T_i = Rz(theta_i + offset_i) Tx(a_i) Tz(d_i) Rx(alpha_i) Ry(beta_i)``
with ``theta = q_dh`` and ``q_dh = coupling(q_ctrl)``.

>>> ur10 = load_description("ur10")
>>> ur10.name, ur10.n_joints
('ur10', 6)
"""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import numpy as np

from kinematics.dataset import temperature_name
from kinematics.description_types import COUPLINGS, JointDH, RobotDescription, SensorRanges
from kinematics.errors import DescriptionError
from kinematics.toml_io import load_toml
from kinematics.transforms import transform_from_xyz_rpy, xyz_rpy_from_transform

ROBOTS_DIR = Path(__file__).parent / "robots"
_JOINT_KEYS = {"a_m", "d_m", "alpha_deg", "beta_deg", "offset_deg", "lower_deg", "upper_deg"}
_JOINT_KEYS_OPTIONAL = {"beta_deg", "offset_deg", "mass_kg", "com_m"}

__all__ = [
    "COUPLINGS",
    "ROBOTS_DIR",
    "JointDH",
    "RobotDescription",
    "SensorRanges",
    "description_from_dict",
    "description_to_toml",
    "load_description",
]


def load_description(source: str | Path) -> RobotDescription:
    """A description from a shipped name (``"ur10"``), a TOML path or a URDF path.

    A TOML file may instead point at a URDF (``urdf = "arm.urdf"``, relative to the TOML file,
    with an optional ``tip_link``, ``coupling`` and ``[sensors]``).
    """
    path = Path(source)
    if path.suffix == ".urdf":
        from kinematics.urdf import description_from_urdf  # urdf.py builds on this module

        return description_from_urdf(path)
    if path.suffix != ".toml":
        shipped = ROBOTS_DIR / f"{source}.toml"
        if not shipped.exists():
            names = sorted(p.stem for p in ROBOTS_DIR.glob("*.toml"))
            raise DescriptionError(f"unknown robot {str(source)!r}; shipped: {', '.join(names)}")
        path = shipped

    def build(raw: dict) -> RobotDescription:
        if "urdf" in raw:
            return _description_from_urdf_entry(path, raw)
        return description_from_dict(raw)

    return load_toml(path, "robot description", build, DescriptionError)


def _description_from_urdf_entry(path: Path, raw: dict) -> RobotDescription:
    """A TOML entry that names a URDF, with the TOML's coupling and sensor ranges on top."""
    from kinematics.urdf import description_from_urdf  # urdf.py builds on this module

    desc = description_from_urdf(
        path.parent / raw["urdf"], raw.get("tip_link"), name=raw.get("name")
    )
    ranges, links = _sensors(raw)
    return replace(
        desc, coupling=str(raw.get("coupling", "none")), sensors=ranges, temperature_links=links
    )


def _sensors(raw: dict) -> tuple[SensorRanges, tuple[tuple[str, tuple[int, ...]], ...]]:
    """The ``[sensors]`` table: declared ranges and the optional ``temperature_links`` map
    (channel name, with or without ``temp_``, -> a link number or a list of them)."""
    table = dict(raw.get("sensors", {}))
    links_raw = table.pop("temperature_links", {})
    if not isinstance(links_raw, dict):
        raise DescriptionError("sensors.temperature_links must be a table of channel = link(s)")
    links = []
    for channel, value in links_raw.items():
        values = value if isinstance(value, list) else [value]
        if not all(isinstance(v, int) and not isinstance(v, bool) for v in values):
            raise DescriptionError(
                f"sensors.temperature_links.{channel}: links are joint numbers, got {value!r}"
            )
        links.append((temperature_name(str(channel)), tuple(int(v) for v in values)))
    try:
        return SensorRanges(**table), tuple(links)
    except TypeError as exc:
        raise DescriptionError(f"sensors: {exc}") from None


def description_from_dict(raw: dict) -> RobotDescription:
    """Build a description from the parsed TOML layout of DESIGN.md."""
    if "name" not in raw:
        raise DescriptionError("missing field 'name'")
    rows = raw.get("joint")
    if not isinstance(rows, list) or not rows:
        raise DescriptionError("missing [[joint]] tables")
    joints = []
    for i, row in enumerate(rows, start=1):
        missing = (_JOINT_KEYS - _JOINT_KEYS_OPTIONAL) - row.keys()
        unknown = row.keys() - _JOINT_KEYS - _JOINT_KEYS_OPTIONAL
        if missing:
            raise DescriptionError(f"joint {i}: missing field(s) {', '.join(sorted(missing))}")
        if unknown:
            raise DescriptionError(f"joint {i}: unknown field(s) {', '.join(sorted(unknown))}")
        values = {
            k: (tuple(float(x) for x in v) if k == "com_m" else float(v)) for k, v in row.items()
        }
        if len(values.get("com_m", (0, 0, 0))) != 3:
            raise DescriptionError(f"joint {i}: com_m must have 3 values")
        try:
            joints.append(JointDH(**values))
        except DescriptionError as exc:
            raise DescriptionError(f"joint {i}: {exc}") from None
    tool_raw = raw.get("tool", {})
    tool = transform_from_xyz_rpy(
        tool_raw.get("xyz_m", (0.0, 0.0, 0.0)), np.deg2rad(tool_raw.get("rpy_deg", (0.0, 0.0, 0.0)))
    )
    return RobotDescription(
        name=str(raw["name"]),
        joints=tuple(joints),
        coupling=str(raw.get("coupling", "none")),
        convention=str(raw.get("convention", "dh_hayati")),
        tool=tool,
        sensors=_sensors(raw)[0],
        temperature_links=_sensors(raw)[1],
    )


def description_to_toml(desc: RobotDescription) -> str:
    """The TOML text that :func:`load_description` reads back into ``desc``."""
    xyz, rpy = xyz_rpy_from_transform(desc.tool)
    lines = [
        f'name = "{desc.name}"',
        f'convention = "{desc.convention}"',
        f'coupling = "{desc.coupling}"',
        "",
    ]
    for j in desc.joints:
        lines += ["[[joint]]"]
        for key in ("a_m", "d_m", "alpha_deg", "beta_deg", "offset_deg", "lower_deg", "upper_deg"):
            lines.append(f"{key} = {getattr(j, key)!r}")
        lines.append(f"mass_kg = {j.mass_kg!r}")
        lines.append(f"com_m = [{', '.join(repr(float(c)) for c in j.com_m)}]")
        lines.append("")
    lines += [
        "[tool]",
        f"xyz_m = [{', '.join(repr(float(v)) for v in xyz)}]",
        f"rpy_deg = [{', '.join(repr(float(v)) for v in np.rad2deg(rpy))}]",
        "",
        "[sensors]",
        f"temperature_min_c = {desc.sensors.temperature_min_c!r}",
        f"temperature_max_c = {desc.sensors.temperature_max_c!r}",
        f"deflection_max_rad = {desc.sensors.deflection_max_rad!r}",
        "",
    ]
    if desc.temperature_links:
        lines += ["[sensors.temperature_links]"]
        lines += [f"{_key(c)} = {list(links)!r}" for c, links in desc.temperature_links]
        lines += [""]
    return "\n".join(lines)


def _key(name: str) -> str:
    """A TOML key: bare when it can be, else quoted."""
    bare = name and all(ch.isascii() and (ch.isalnum() or ch in "_-") for ch in name)
    return name if bare else '"' + name.replace("\\", "\\\\").replace('"', '\\"') + '"'
