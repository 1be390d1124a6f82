"""The ``Source`` family: a loop that reads a device (or a simulator) and publishes samples.

A real controller, tracker or DAQ adapter is one small module: subclass :class:`Source`,
implement :meth:`Source.run` (read, convert to a ``stream.messages`` sample, ``self.publish``)
while ``self.running``; open the device in ``setup()`` and close it in ``cleanup(failed)``.
"""

from __future__ import annotations

import abc
import threading

import zenoh

from stream.bus import publisher
from stream.messages import JointSample, TemperatureSample, TrackerSample, encode, key

_STREAM = {JointSample: "joints", TrackerSample: "tracker", TemperatureSample: "temperature"}


class Source(abc.ABC):
    """Publishes one robot's source samples on ``robocal/<cell>/<robot>/<stream>``."""

    def __init__(self, session: zenoh.Session, cell: str, robot: str) -> None:
        self.cell, self.robot = cell, robot
        self._session = session
        self._publishers = {}
        self._stop = threading.Event()
        self.published = 0

    @property
    def running(self) -> bool:
        return not self._stop.is_set()

    def stop(self) -> None:
        """Ask :meth:`run` to return at its next check of ``running``."""
        self._stop.set()

    def setup(self) -> None:
        """Open the device; a no-op hook by default."""

    def cleanup(self, failed: bool) -> None:
        """Close the device; a no-op hook by default."""

    @abc.abstractmethod
    def run(self) -> None:
        """Read and :meth:`publish` samples while :attr:`running`."""

    def publish(self, sample: JointSample | TrackerSample | TemperatureSample) -> None:
        self.publish_raw(_STREAM[type(sample)], encode(sample))

    def publish_raw(self, stream: str, payload: bytes) -> None:
        """Publish an already encoded payload on ``stream`` (adapters that forward JSON)."""
        if stream not in self._publishers:
            self._publishers[stream] = publisher(self._session, key(self.cell, self.robot, stream))
        self._publishers[stream].put(payload)
        self.published += 1

    def start(self) -> None:
        """``setup()``, ``run()``, ``cleanup(failed)`` in this thread."""
        self.setup()
        failed = True
        try:
            self.run()
            failed = False
        finally:
            self.cleanup(failed)
            for pub in self._publishers.values():
                pub.undeclare()
            self._publishers.clear()
