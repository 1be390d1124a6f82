"""Robot identity: which description a dataset is of, by one rule used by every command.

A dataset's ``meta.robot`` is a reference, resolved like a ``--robot`` argument
(:func:`~kinematics.description.load_description`): a shipped name (``"ur10"``), or a path to
a ``.toml`` / ``.urdf`` file, absolute or relative to the working directory. A relative path
that is not found there is looked up next to the dataset file, where the file travels with it.

A dataset matches a description by content: the same number of joints and the same robot name
(the ``name`` inside a referenced file, not the file's path). A description given explicitly
(``--robot``, e.g. a calibrated copy) must match the dataset's own robot by that rule; when the
dataset's reference cannot be read (a file left behind on another machine), the explicit one is
checked by joint count only.

>>> from kinematics.description import load_description
>>> reference_name("ur10"), is_path_reference("cell/arm.toml")
('ur10', True)
"""

from __future__ import annotations

from pathlib import Path

from kinematics.dataset import Dataset
from kinematics.description import RobotDescription, load_description
from kinematics.errors import DatasetError, DescriptionError

_FILE_SUFFIXES = (".toml", ".urdf")


def is_path_reference(ref: str | Path) -> bool:
    """Whether ``ref`` names a description file rather than a shipped robot."""
    text = str(ref)
    return Path(text).suffix in _FILE_SUFFIXES or "/" in text or "\\" in text


def resolve_reference(ref: str | Path, dataset_path: str | Path | None = None) -> Path | str:
    """The loadable form of ``ref``: a shipped name unchanged, a path made to exist if it can
    (as given, else next to ``dataset_path``); an unresolvable path is returned as given."""
    if not is_path_reference(ref):
        return str(ref)
    path = Path(ref).expanduser()
    if path.exists() or path.is_absolute() or dataset_path is None:
        return path
    beside = Path(dataset_path).parent / path
    return beside if beside.exists() else path


def load_reference(ref: str | Path, dataset_path: str | Path | None = None) -> RobotDescription:
    """The description ``ref`` names (see :func:`resolve_reference`)."""
    return load_description(resolve_reference(ref, dataset_path))


def reference_name(ref: str | Path, dataset_path: str | Path | None = None) -> str:
    """The robot name a reference stands for: a shipped name itself, a file's ``name``."""
    if not is_path_reference(ref):
        return str(ref)
    return load_reference(ref, dataset_path).name


def check_match(
    desc: RobotDescription, ds: Dataset, dataset_path: str | Path | None = None
) -> None:
    """Raise :class:`DatasetError` when ``ds`` is not of robot ``desc`` (joint count, name)."""
    if ds.n_joints != desc.n_joints:
        raise DatasetError(
            f"dataset has {ds.n_joints} joint columns, robot {desc.name!r} has {desc.n_joints}"
        )
    try:
        name = reference_name(ds.meta.robot, dataset_path)
    except DescriptionError:
        if is_path_reference(ds.meta.robot):
            return  # the dataset's file is unreadable here: joint count only
        raise
    if name != desc.name:
        shown = ds.meta.robot if name == ds.meta.robot else f"{ds.meta.robot} ({name})"
        raise DatasetError(f"dataset is of robot {shown!r}, description is {desc.name!r}")


def description_for(
    ds: Dataset, robot: str | Path | None = None, dataset_path: str | Path | None = None
) -> RobotDescription:
    """The description of ``ds``: ``robot`` when given (checked to match), else the dataset's
    ``meta.robot``; a dataset whose reference cannot be read and no ``robot`` -> one line."""
    if robot is not None:
        desc = load_reference(robot)
    else:
        try:
            desc = load_reference(ds.meta.robot, dataset_path)
        except DescriptionError as exc:
            raise DatasetError(
                f"dataset's robot {ds.meta.robot!r} cannot be loaded ({exc}); pass --robot"
            ) from None
    check_match(desc, ds, dataset_path)
    return desc


__all__ = [
    "check_match",
    "description_for",
    "is_path_reference",
    "load_reference",
    "reference_name",
    "resolve_reference",
]
