"""Sources: adapters that publish joint, tracker and temperature samples on the bus."""

from stream.sources._base import Source
from stream.sources.sim import SimCellSource

__all__ = ["SimCellSource", "Source"]
