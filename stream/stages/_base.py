"""The stage shell: subscriptions feeding one worker thread, drop counting, diagnostics,
a liveliness token, and queryables answered from their own thread.

A stage's logic lives in pure objects (window.Joiner, learner_core.LearnerCore,
compensation.compensate); a stage only decodes, calls them and publishes. A message that fails
validation is counted under its reason, logged at a bounded rate and dropped; the stage runs on.
"""

from __future__ import annotations

import queue
import threading
import time
from collections.abc import Callable

import zenoh

from kinematics.errors import RobocalError
from stream.bus import Received, Worker, declare_alive, publisher
from stream.log import JsonLogger
from stream.messages import DropCounter, RejectedMessageError, encode, key


class Stage:
    """Base of the pipeline stages of one robot; subclasses implement :meth:`handle`."""

    name = "stage"

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
        self.worker = Worker(f"{self.name}-{robot}", self._handle, idle=self._idle)
        self._token = declare_alive(session, cell, robot, self.name)

    def key(self, stream: str) -> str:
        return key(self.cell, self.robot, stream)

    def subscribe(self, stream: str) -> None:
        self._subs.append(self.session.declare_subscriber(self.key(stream), self.worker.callback))

    def answer(self, stream: str, reply: Callable[[zenoh.Query], None]) -> None:
        """Declare a queryable on ``stream``; ``reply(query)`` runs on its own thread."""
        qw = QueryWorker(f"{self.name}-{self.robot}-query", reply)
        self._queryables.append((self.session.declare_queryable(self.key(stream), qw.callback), qw))

    def put(self, stream: str, payload: bytes) -> None:
        if stream not in self._pubs:
            self._pubs[stream] = publisher(self.session, self.key(stream))
        self._pubs[stream].put(payload)

    def _handle(self, item: Received) -> None:
        try:
            self.handle(item)
        except RobocalError as exc:  # bad input: count, log at a bounded rate, go on
            reason = exc.reason if isinstance(exc, RejectedMessageError) else "invalid"
            self.counter.drop(reason)
            self.log.limited(
                "message_dropped",
                key=f"{self.name}:{reason}",
                stage=self.name,
                robot=self.robot,
                topic=item.key,
                reason=reason,
                detail=str(exc),
            )

    def handle(self, item: Received) -> None:
        """Decode and process one received sample."""
        raise NotImplementedError

    def _idle(self, now: float) -> None:
        self.on_idle(now)
        if now - self._last_diag >= 1.0:
            self._last_diag = now
            self.publish_diagnostics(now)

    def on_idle(self, now: float) -> None:
        """Periodic work (at least every 0.2 s); a no-op hook by default."""

    def publish_diagnostics(self, now: float | None = None) -> None:
        self.put("diagnostics", encode(self.counter.diagnostics(now or time.time())))

    def drain(self, timeout_s: float = 60.0) -> bool:
        """Wait until every received sample is handled."""
        return self.worker.drain(timeout_s)

    def finish(self) -> None:
        """Last work before closing (flush, checkpoint); a no-op hook by default."""

    def close(self) -> None:
        """Stop receiving, handle what is queued, ``finish()``, publish diagnostics, leave."""
        for sub in self._subs:
            sub.undeclare()
        self._subs.clear()
        self.worker.stop()
        self.finish()
        self.publish_diagnostics()
        for q, qw in self._queryables:
            q.undeclare()
            qw.stop()
        self._queryables.clear()
        for pub in self._pubs.values():
            pub.undeclare()
        self._pubs.clear()
        self._token.undeclare()
        if self.worker.error is not None:
            raise self.worker.error


class QueryWorker:
    """Answers queries on a thread of its own, so a Zenoh callback only enqueues."""

    def __init__(self, name: str, reply: Callable[[zenoh.Query], None]) -> None:
        self._queue: queue.Queue[zenoh.Query | None] = queue.Queue()
        self._reply = reply
        self.error: BaseException | None = None
        self._thread = threading.Thread(target=self._loop, name=name, daemon=True)
        self._thread.start()

    def callback(self, query: zenoh.Query) -> None:
        self._queue.put(query)

    def _loop(self) -> None:
        while (query := self._queue.get()) is not None:
            try:
                self._reply(query)
            except RobocalError as exc:  # a bad request: the asker gets the one-line reason
                query.reply_err(str(exc).encode())
            except Exception as exc:  # a bug must not silence the queryable; kept for the owner
                self.error = exc
                query.reply_err(f"internal error: {type(exc).__name__}: {exc}".encode())
            finally:
                query.drop()

    def stop(self) -> None:
        self._queue.put(None)
        self._thread.join(10.0)
