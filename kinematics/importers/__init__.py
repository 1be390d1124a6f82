"""Importers that turn other measurement layouts into the dataset format of DESIGN.md."""

from kinematics.importers.ipa import IpaImport, import_series

__all__ = ["IpaImport", "import_series"]
