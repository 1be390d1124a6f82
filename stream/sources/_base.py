"""The ``Source`` family: a loop that reads a device (or a file) and publishes samples.

A controller, tracker or DAQ adapter is one small module: subclass :class:`Source`, implement
:meth:`Source.run` (read, convert to a ``wire`` sample, ``self.publish``) while
``self.running``; open the device in ``setup()`` and close it in ``cleanup(failed)``. What a
source could not deliver (a device that dropped, a payload it could not decode, a gap in the
device's sequence numbers) is counted by reason with :meth:`Source.undelivered`; the counts go
out as :class:`~wire.messages.Diagnostics` (stage ``source_<kind>``) on
``robocal/<cell>/<robot>/diagnostics`` every ``diagnostics_period_s`` and when the source ends.
"""

from __future__ import annotations

import abc
import contextlib
import threading
import time

import zenoh

from stream.bus import publisher, wait_matched
from wire import (
    DropCounter,
    JointSample,
    RejectedMessageError,
    TemperatureSample,
    TrackerSample,
    encode,
    key,
)

_STREAM = {JointSample: "joints", TrackerSample: "tracker", TemperatureSample: "temperature"}


class Source(abc.ABC):
    """Publishes one robot's source samples on ``robocal/<cell>/<robot>/<stream>``."""

    kind = "source"
    diagnostics_period_s = 1.0

    def __init__(self, session: zenoh.Session, cell: str, robot: str) -> None:
        self.cell, self.robot = cell, robot
        self._session = session
        self._publishers = {}
        self._stop = threading.Event()
        self._lock = threading.Lock()
        self.published = 0
        self.counter = DropCounter(f"source_{self.kind}")

    @property
    def running(self) -> bool:
        return not self._stop.is_set()

    def stop(self) -> None:
        """Ask :meth:`run` to return at its next check of ``running``."""
        self._stop.set()

    def wait(self, seconds: float) -> bool:
        """Sleep up to ``seconds`` (s); True when asked to stop meanwhile."""
        return self._stop.wait(seconds)

    def setup(self) -> None:
        """Open the device; a no-op hook by default."""

    def cleanup(self, failed: bool) -> None:
        """Close the device; a no-op hook by default."""

    @abc.abstractmethod
    def run(self) -> None:
        """Read and :meth:`publish` samples while :attr:`running`."""

    def undelivered(self, reason: str, n: int = 1) -> None:
        """Count ``n`` samples of the device that were not published, under ``reason``."""
        with self._lock:
            self.counter.drop(reason, n)

    def publish(self, sample: JointSample | TrackerSample | TemperatureSample) -> bool:
        """Validate and publish one sample; an invalid one is counted under its reason."""
        try:
            sample.check()
        except RejectedMessageError as exc:
            self.undelivered(exc.reason)
            return False
        self.publish_raw(_STREAM[type(sample)], encode(sample))
        return True

    def _publisher(self, stream: str) -> zenoh.Publisher:
        if stream not in self._publishers:
            self._publishers[stream] = publisher(self._session, key(self.cell, self.robot, stream))
        return self._publishers[stream]

    def await_subscribers(
        self, timeout_s: float, streams: tuple[str, ...] = tuple(_STREAM.values())
    ) -> list[str]:
        """Wait up to ``timeout_s`` (s) until each of the ``streams`` this source will publish
        has a subscriber, so that a replay's first samples are not lost to a window that is
        still starting; the keys still without one."""
        pubs = [self._publisher(stream) for stream in streams]
        return wait_matched(pubs, timeout_s, self._stop)

    def publish_raw(self, stream: str, payload: bytes) -> None:
        """Publish an already encoded payload on ``stream`` (adapters that forward JSON)."""
        self._publisher(stream).put(payload)
        with self._lock:
            self.published += 1
            self.counter.accept()

    def diagnostics(self) -> dict:
        """Published and undelivered counts (by reason) so far."""
        with self._lock:
            return {"published": self.published, "undelivered": dict(self.counter.dropped)}

    def publish_diagnostics(self) -> None:
        """Put the counts on ``robocal/<cell>/<robot>/diagnostics``."""
        with self._lock:
            diag = self.counter.diagnostics(time.time())
        self._session.put(key(self.cell, self.robot, "diagnostics"), encode(diag))

    def _report(self) -> None:
        while not self._stop.wait(self.diagnostics_period_s):
            self.publish_diagnostics()

    def start(self) -> None:
        """``setup()``, ``run()``, ``cleanup(failed)`` in this thread (diagnostics beside)."""
        reporter = threading.Thread(target=self._report, name=f"{self.kind}-diag", daemon=True)
        reporter.start()
        failed = True
        try:
            self.setup()
            self.run()
            failed = False
        finally:
            self._stop.set()
            try:
                self.cleanup(failed)
            finally:
                reporter.join(self.diagnostics_period_s + 1.0)
                for pub in self._publishers.values():
                    pub.undeclare()
                self._publishers.clear()
                with contextlib.suppress(zenoh.ZError):  # a closing session: counts stay here
                    self.publish_diagnostics()
