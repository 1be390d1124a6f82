"""The stage shell: subscriptions feeding one worker thread, drop counting, diagnostics,
a liveliness token, and queryables answered from their own thread.

A stage's logic lives in pure objects (window.Joiner, learner_core.LearnerCore,
compensation.compensate); a stage only decodes, calls them and publishes. No message stops a
stage: whatever a handler or ``on_idle`` raises is counted under its reason (a
:class:`RejectedMessageError`'s, ``invalid`` for other errors, ``idle_error`` in ``on_idle``),
logged at a bounded rate and dropped; the stage runs on. Only resource failures (``OSError``:
a full disk, a read-only state directory; ``MemoryError``) are fatal: the worker keeps the
error, its thread ends, and the daemon's supervisor stops the process with one line. State
writes go through :meth:`Stage.persist`: with ``on_disk_full = "wait"`` a write that fails for
lack of space or permission is retried every ``retry_s`` until it succeeds (one line when it
starts waiting, one when it resumes) instead of ending the stage.

Memory is bounded: a sample larger than :data:`~wire.messages.MAX_PAYLOAD_BYTES` (models:
:data:`MAX_MODEL_BYTES`) is dropped as ``too_large`` before it is copied, and what the worker's
bounded queue cannot take is dropped as ``overload``; both are counted in the diagnostics.
"""

from __future__ import annotations

import contextlib
import errno
import queue
import threading
import time
from collections.abc import Callable
from pathlib import Path

import zenoh

from kinematics.dataset import remove_stale_temporaries
from kinematics.errors import RobocalError
from stream.bus import declare_alive, publisher
from stream.log import JsonLogger
from stream.state import describe_os_error
from stream.worker import Received, Worker
from wire import MAX_PAYLOAD_BYTES, DropCounter, RejectedMessageError, encode, key

#: The largest model snapshot a stage takes (bytes); every other stream: MAX_PAYLOAD_BYTES.
MAX_MODEL_BYTES = 64 * 2**20
#: What ``on_disk_full`` may say: end the stage (the daemon exits 2) or wait until writable.
DISK_FULL_POLICIES = ("stop", "wait")
#: OSErrors that waiting can cure (space or permission given back), the rest are fatal at once.
WAITABLE_ERRNOS = {errno.ENOSPC, errno.EDQUOT, errno.EROFS, errno.EACCES, errno.EPERM}


def is_fatal(exc: BaseException) -> bool:
    """Whether an error ends the stage: resources (``OSError``, ``MemoryError``) or an exit."""
    if isinstance(exc, RobocalError):
        return False
    return isinstance(exc, OSError | MemoryError) or not isinstance(exc, Exception)


def drop_reason(exc: BaseException) -> str:
    """The drop counter of a non-fatal error: the message's own reason, else ``invalid``."""
    return exc.reason if isinstance(exc, RejectedMessageError) else "invalid"


class Stage:
    """Base of the pipeline stages of one robot; subclasses implement :meth:`handle`."""

    name = "stage"
    #: ``"stop"`` or ``"wait"`` (see :meth:`persist`); the daemon sets it from its config.
    on_disk_full = "stop"
    retry_s = 1.0

    def __init__(
        self, session: zenoh.Session, cell: str, robot: str, logger: JsonLogger | None = None
    ) -> None:
        self.session, self.cell, self.robot = session, cell, robot
        self.log = logger or JsonLogger()
        self.counter = DropCounter(self.name)
        self._subs: list[zenoh.Subscriber] = []
        self._queryables: list[tuple[zenoh.Queryable, QueryWorker]] = []
        self._pubs: dict[str, zenoh.Publisher] = {}
        self._last_diag = 0.0
        self._closing = threading.Event()
        #: Samples taken off the queue and handled (accepted or dropped by the handler).
        self.handled = 0
        self._worker_drops = {"overload": 0, "too_large": 0, "shutdown": 0}
        self.worker = Worker(f"{self.name}-{robot}", self._handle, idle=self._idle)
        self._token = declare_alive(session, cell, robot, self.name)

    def key(self, stream: str) -> str:
        return key(self.cell, self.robot, stream)

    def subscribe(self, stream: str) -> None:
        limit = MAX_MODEL_BYTES if stream == "model" else MAX_PAYLOAD_BYTES
        offer = self.worker.offer
        self._subs.append(
            self.session.declare_subscriber(self.key(stream), lambda s: offer(s, limit))
        )

    def persist(self, write: Callable[[], object], what: str, path: Path | None = None) -> None:
        """Run the state write ``write()``; on a full disk or lost permission either re-raise
        (``on_disk_full = "stop"``: fatal) or retry every ``retry_s`` until it succeeds or the
        stage closes (``"wait"``). Once a retry succeeds, the temporaries beside the stage's own
        file ``path`` are removed: a directory made read-only mid-write keeps the atomic
        writer from deleting its temporary."""
        waited = 0
        while True:
            try:
                write()
            except OSError as exc:
                if self.on_disk_full != "wait" or exc.errno not in WAITABLE_ERRNOS:
                    raise
                if self._closing.is_set():
                    raise
                if not waited:
                    self.log.log(
                        "error",
                        "state_unwritable",
                        stage=self.name,
                        robot=self.robot,
                        what=what,
                        cause=describe_os_error(exc),
                        action=f"waiting, retry every {self.retry_s} s",
                    )
                waited += 1
                self._closing.wait(self.retry_s)
                continue
            if waited:
                if path is not None:
                    remove_stale_temporaries(path)
                self.log.info("state_writable", stage=self.name, robot=self.robot, what=what)
            return

    def answer(self, stream: str, reply: Callable[[zenoh.Query], None]) -> None:
        """Declare a queryable on ``stream``; ``reply(query)`` runs on its own thread."""
        qw = QueryWorker(f"{self.name}-{self.robot}-query", reply)
        self._queryables.append((self.session.declare_queryable(self.key(stream), qw.callback), qw))

    def put(self, stream: str, payload: bytes) -> None:
        if stream not in self._pubs:
            self._pubs[stream] = publisher(self.session, self.key(stream))
        self._pubs[stream].put(payload)

    def _handle(self, item: Received) -> None:
        self.handled += 1
        try:
            self.handle(item)
        except BaseException as exc:  # bad input: count, log at a bounded rate, go on
            if is_fatal(exc):
                raise
            self._dropped(drop_reason(exc), exc, item.key)

    def _dropped(self, reason: str, exc: BaseException, topic: str) -> None:
        self.counter.drop(reason)
        detail = str(exc) if isinstance(exc, RobocalError) else f"{type(exc).__name__}: {exc}"
        self.log.limited(
            "message_dropped",
            key=f"{self.name}:{reason}",
            stage=self.name,
            robot=self.robot,
            topic=topic,
            reason=reason,
            detail=detail[:300],
        )

    @property
    def failure(self) -> BaseException | None:
        """The fatal error that ended the stage's worker, or None while it runs."""
        return self.worker.error

    def handle(self, item: Received) -> None:
        """Decode and process one received sample."""
        raise NotImplementedError

    def _idle(self, now: float) -> None:
        try:
            self.on_idle(now)
            if now - self._last_diag >= 1.0:
                self._last_diag = now
                self.publish_diagnostics(now)
        except BaseException as exc:
            if is_fatal(exc):
                raise
            self._dropped("idle_error", exc, self.name)

    def on_idle(self, now: float) -> None:
        """Periodic work (at least every 0.2 s); a no-op hook by default."""

    def publish_diagnostics(self, now: float | None = None) -> None:
        self.count_worker_drops()
        self.put("diagnostics", encode(self.counter.diagnostics(now or time.time())))

    def count_worker_drops(self) -> None:
        """Add the worker's drops since the last call (``overload``, ``too_large``,
        ``shutdown``) to the stage's counter."""
        w = self.worker
        for reason, n in (
            ("overload", w.overload),
            ("too_large", w.too_large),
            ("shutdown", w.abandoned),
        ):
            if n > self._worker_drops[reason]:
                self.counter.drop(reason, n - self._worker_drops[reason])
                self._worker_drops[reason] = n

    def drain(self, timeout_s: float = 60.0) -> bool:
        """Wait until every received sample is handled."""
        return self.worker.drain(timeout_s)

    def finish(self) -> None:
        """Last work before closing (flush, checkpoint); a no-op hook by default."""

    def unsubscribe(self) -> None:
        """Stop receiving (what is queued is still handled; a waiting :meth:`persist` ends)."""
        self._closing.set()
        for sub in self._subs:
            _quietly(sub.undeclare)
        self._subs.clear()

    def close(self, timeout_s: float = 60.0) -> BaseException | None:
        """Stop receiving, handle what is queued within ``timeout_s`` (abandon the rest),
        ``finish()`` unless the worker is stuck or dead, publish diagnostics, leave. Never
        raises: returns the fatal error of the worker or of ``finish()``, or None."""
        self.unsubscribe()
        stopped = self.worker.stop(timeout_s)
        failure = self.worker.error
        if stopped and failure is None:
            try:
                self.finish()
            except Exception as exc:  # a full disk at the last checkpoint: reported, not raised
                failure = exc
        if not stopped:
            self.log.info("stage_abandoned", stage=self.name, robot=self.robot, after_s=timeout_s)
        _quietly(self.publish_diagnostics)
        for q, qw in self._queryables:
            _quietly(q.undeclare)
            qw.stop()
        self._queryables.clear()
        for pub in self._pubs.values():
            _quietly(pub.undeclare)
        self._pubs.clear()
        _quietly(self._token.undeclare)
        return failure


def _quietly(fn: Callable[[], object]) -> None:
    """Call ``fn``; a failure while leaving the bus (session already gone) is ignored."""
    with contextlib.suppress(Exception):
        fn()


class QueryWorker:
    """Answers queries on a thread of its own, so a Zenoh callback only enqueues."""

    def __init__(self, name: str, reply: Callable[[zenoh.Query], None]) -> None:
        self._queue: queue.Queue[zenoh.Query | None] = queue.Queue()
        self._reply = reply
        self.errors = 0
        self._thread = threading.Thread(target=self._loop, name=name, daemon=True)
        self._thread.start()

    def callback(self, query: zenoh.Query) -> None:
        self._queue.put(query)

    def _loop(self) -> None:
        while (query := self._queue.get()) is not None:
            try:
                self._reply(query)
            except RobocalError as exc:  # a bad request: the asker gets the one-line reason
                _quietly(lambda e=exc: query.reply_err(str(e).encode()))
            except Exception as exc:  # any other failure is named too; the queryable goes on
                self.errors += 1
                text = f"invalid: {type(exc).__name__}: {exc}"[:300]
                _quietly(lambda t=text: query.reply_err(t.encode()))
            finally:
                _quietly(query.drop)

    def stop(self) -> None:
        self._queue.put(None)
        self._thread.join(10.0)
