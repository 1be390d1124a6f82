"""Queue-fed workers: a Zenoh callback only puts a :class:`Received` item on a bounded queue, and
a worker thread does the work, so a callback never blocks the Zenoh runtime and never calls
back into Zenoh. A flood is dropped and counted, not buffered without bound.
"""

from __future__ import annotations

import queue
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass

import zenoh


@dataclass(frozen=True)
class Received:
    """One sample as a worker sees it: key, payload, attachment and receive time (s, epoch)."""

    key: str
    payload: bytes
    attachment: bytes | None
    received_t: float


def _to_received(sample: zenoh.Sample) -> Received:
    att = sample.attachment
    return Received(
        str(sample.key_expr),
        sample.payload.to_bytes(),
        None if att is None else att.to_bytes(),
        time.time(),
    )


@dataclass(frozen=True)
class _Call:
    fn: Callable[[], None]
    done: threading.Event


class Worker:
    """A thread that calls ``handle(item)`` for each queued item; ``stop()`` drains and joins.

    ``idle(now)`` is called at least every ``tick_s`` (periodic work: flush, diagnostics). An
    exception that escapes ``handle`` or ``idle`` is fatal: it is kept in :attr:`error` and the
    thread ends (the owner's supervisor reports it and stops the process). The queue is
    bounded: a payload over ``max_payload_bytes`` is dropped before it is copied (counted in
    :attr:`too_large`), and beyond ``max_queue`` items or ``max_queue_bytes`` of payload waiting
    new samples are dropped (counted in :attr:`overload`), so a flood costs bounded memory.
    """

    def __init__(
        self,
        name: str,
        handle: Callable[[Received], None],
        idle: Callable[[float], None] | None = None,
        tick_s: float = 0.2,
        max_queue: int = 200_000,
        max_queue_bytes: int = 64 * 2**20,
        max_payload_bytes: int = 64 * 2**20,
    ) -> None:
        self.name = name
        self.queue: queue.Queue[Received | None] = queue.Queue(max_queue)
        self.max_queue_bytes, self.max_payload_bytes = max_queue_bytes, max_payload_bytes
        self.queued_bytes = 0
        self._bytes_lock = threading.Lock()
        self._handle = handle
        self._idle = idle
        self._tick = tick_s
        self._abort = threading.Event()
        self.error: BaseException | None = None
        self.overload = 0
        self.too_large = 0
        self.abandoned = 0
        self._thread = threading.Thread(target=self._loop, name=name, daemon=True)
        self._thread.start()

    @property
    def alive(self) -> bool:
        """Whether the thread still runs."""
        return self._thread.is_alive()

    def callback(self, sample: zenoh.Sample) -> None:
        """The Zenoh subscriber callback: enqueue only (drop and count when too large or full)."""
        self.offer(sample, self.max_payload_bytes)

    def offer(self, sample: zenoh.Sample, max_payload_bytes: int) -> None:
        """Enqueue ``sample`` unless its payload exceeds ``max_payload_bytes`` (``too_large``,
        refused before it is copied) or the queue is full (``overload``)."""
        n = len(sample.payload)
        with self._bytes_lock:
            if n > max_payload_bytes:
                self.too_large += 1
                return
            if self.queued_bytes + n > self.max_queue_bytes or self.queue.full():
                self.overload += 1
                return
            self.queued_bytes += n
        try:
            self.queue.put_nowait(_to_received(sample))
        except queue.Full:
            with self._bytes_lock:
                self.queued_bytes -= n
                self.overload += 1

    def _loop(self) -> None:
        next_idle = time.monotonic() + self._tick
        while True:
            try:
                item = self.queue.get(timeout=self._tick)
            except queue.Empty:
                item = ...
            if isinstance(item, Received):
                with self._bytes_lock:
                    self.queued_bytes -= len(item.payload)
            try:
                if item is None:
                    break
                if self._abort.is_set():
                    if isinstance(item, _Call):
                        item.done.set()
                    self.abandoned += item is not ...
                    continue
                if isinstance(item, _Call):
                    try:
                        item.fn()
                    finally:
                        item.done.set()
                elif item is not ...:
                    self._handle(item)
                if self._idle is not None and time.monotonic() >= next_idle:
                    next_idle = time.monotonic() + self._tick
                    self._idle(time.time())
            except BaseException as exc:  # fatal: kept for the supervisor; the thread ends
                self.error = exc
                return
            finally:
                if item is not ...:
                    self.queue.task_done()

    def submit(self, fn: Callable[[], None]) -> threading.Event:
        """Queue ``fn`` to run on the worker thread after what is queued; the returned event is
        set once it has run (or was abandoned). An exception it raises is fatal, as in
        ``handle``."""
        if self.error is not None or not self.alive:
            raise RuntimeError(f"worker {self.name} is not running ({self.error!r})")
        call = _Call(fn, threading.Event())
        self.queue.put(call)
        return call.done

    def call(self, fn: Callable[[], None], timeout_s: float = 60.0) -> None:
        """Run ``fn`` on the worker thread after what is queued; wait for it."""
        done = self.submit(fn)
        deadline = time.monotonic() + timeout_s
        while not done.wait(0.05):
            if self.error is not None or not self.alive:
                raise RuntimeError(f"worker {self.name} ended ({self.error!r})")
            if time.monotonic() > deadline:
                raise TimeoutError(f"worker did not run the call within {timeout_s} s")

    def drain(self, timeout_s: float = 30.0) -> bool:
        """Wait until every enqueued item is handled; False on timeout or a dead thread."""
        deadline = time.monotonic() + timeout_s
        while self.queue.unfinished_tasks and time.monotonic() < deadline:
            if self.error is not None or not self.alive:
                return False
            time.sleep(0.005)
        return not self.queue.unfinished_tasks

    def stop(self, timeout_s: float = 30.0) -> bool:
        """Handle what is queued within ``timeout_s``, abandon the rest (counted in
        :attr:`abandoned`), end the thread; False when it is still busy with one item."""
        try:
            self.queue.put(None, timeout=max(timeout_s, 0.01))
        except queue.Full:
            self._abort.set()
            self.queue.put(None)
        self._thread.join(max(timeout_s, 0.0))
        if self._thread.is_alive():
            self._abort.set()
            self._thread.join(1.0)
        return not self._thread.is_alive()


def subscribe(session: zenoh.Session, key_expr: str, worker: Worker) -> zenoh.Subscriber:
    """Subscribe ``worker`` to ``key_expr`` (samples land on its queue)."""
    return session.declare_subscriber(key_expr, worker.callback)
