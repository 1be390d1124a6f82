"""The simulated cell as a :class:`~stream.sources.Source`: a campaign dataset streamed as the
joint, tracker and temperature samples a real cell would publish (see sim_sources.streaming)."""

from __future__ import annotations

import zenoh

from kinematics.dataset import Dataset
from sim_sources.streaming import StreamingConfig, cell_samples, paced
from stream.sources._base import Source


class SimCellSource(Source):
    """Streams ``ds`` at ``speed`` x real time (``None``: as fast as possible)."""

    kind = "sim"

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

    def samples(self):
        """The samples to stream, in source-time order."""
        return cell_samples(self.ds, self.cfg)

    def run(self) -> None:
        for sample in paced(self.samples(), self.speed, sleep=self.wait):
            if not self.running:
                return
            self.publish(sample)
