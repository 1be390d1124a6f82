"""Lazy package exports (PEP 562): a package names what it exports and where, and a submodule
is imported only when one of its names is first used (``robocal --help`` stays light).

>>> getattr_ = lazy_exports("kinematics", {"errors": ("RobocalError",)})
>>> getattr_("RobocalError").__name__
'RobocalError'
"""

from __future__ import annotations

from collections.abc import Callable
from importlib import import_module
from typing import Any


def lazy_exports(package: str, where: dict[str, tuple[str, ...]]) -> Callable[[str], Any]:
    """A module ``__getattr__`` for ``package``: each name in ``where[submodule]`` comes from
    ``package.submodule``, imported on first use; any other name is an AttributeError."""
    module_of = {name: module for module, names in where.items() for name in names}

    def exported(name: str) -> Any:
        if name not in module_of:
            raise AttributeError(f"module {package!r} has no attribute {name!r}")
        return getattr(import_module(f"{package}.{module_of[name]}"), name)

    return exported
