"""The simulated cell as a :class:`~stream.sources.Source`: a campaign dataset streamed as the
joint, tracker and temperature samples a real cell would publish (see sim_sources.streaming)."""

from __future__ import annotations

import zenoh

from kinematics.dataset import Dataset, temperature_columns
from sim_sources.streaming import StreamingConfig, cell_samples, paced
from stream.sources._base import Source


class SimCellSource(Source):
    """Streams ``ds`` at ``speed`` x real time (``None``: as fast as possible), once each stream
    has a subscriber or ``wait_subscribers_s`` (s) have passed: a replay can wait for its
    window, where a live device cannot."""

    kind = "sim"

    def __init__(
        self,
        session: zenoh.Session,
        cell: str,
        robot: str,
        ds: Dataset,
        cfg: StreamingConfig,
        speed: float | None = None,
        wait_subscribers_s: float = 10.0,
    ) -> None:
        super().__init__(session, cell, robot)
        self.ds, self.cfg, self.speed = ds, cfg, speed
        self.wait_subscribers_s = wait_subscribers_s
        self.unheard: list[str] = []

    def setup(self) -> None:
        self.unheard = self.await_subscribers(self.wait_subscribers_s, self.streams())

    def streams(self) -> tuple[str, ...]:
        """The streams it publishes: temperature only where the dataset has a thermometer."""
        return (
            "joints",
            "tracker",
            *(("temperature",) if temperature_columns(self.ds.table) else ()),
        )

    def diagnostics(self) -> dict:
        """The counts, and the streams that had no subscriber when streaming began."""
        return {**super().diagnostics(), **({"unheard": self.unheard} if self.unheard else {})}

    def samples(self):
        """The samples to stream, in source-time order."""
        return cell_samples(self.ds, self.cfg)

    def run(self) -> None:
        for sample in paced(self.samples(), self.speed, sleep=self.wait):
            if not self.running:
                return
            self.publish(sample)
