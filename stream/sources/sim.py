"""The simulated cell as a :class:`~stream.sources.Source`: a campaign dataset streamed as the
joint, tracker and temperature samples a real cell would publish (see sim_sources.streaming)."""

from __future__ import annotations

import zenoh

from kinematics.dataset import Dataset
from sim_sources.streaming import StreamingConfig, cell_samples, paced
from stream.sources._base import Source


class SimCellSource(Source):
    """Streams ``ds`` at ``speed`` x real time (``None``: as fast as possible)."""

    def __init__(
        self,
        session: zenoh.Session,
        cell: str,
        robot: str,
        ds: Dataset,
        cfg: StreamingConfig,
        speed: float | None = None,
    ) -> None:
        super().__init__(session, cell, robot)
        self.ds, self.cfg, self.speed = ds, cfg, speed

    def run(self) -> None:
        for sample in paced(cell_samples(self.ds, self.cfg), self.speed):
            if not self.running:
                return
            self.publish(sample)
