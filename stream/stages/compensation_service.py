"""The compensation service: a queryable on ``.../compensate`` using the newest model.

Request payload: JSON of :class:`~stream.compensation.CompensationRequest` (``schema``
``robocal.compensate.request``, ``version``); reply: JSON of
:class:`~stream.compensation.CompensationReply`, or a Zenoh error reply with one line
(bad request, no model yet). The service follows ``.../model`` and, on start, asks the
``.../model`` queryable for the latest snapshot, so it uses the newest model within one update.
"""

from __future__ import annotations

import threading

import zenoh

from kinematics.model import RobotModel
from learner.model import ErrorModel
from learner.snapshot import snapshot_from_bytes
from stream.bus import Received
from stream.compensation import CompensationConfig, CompensationRequest, compensate
from stream.log import JsonLogger
from stream.messages import RejectedMessageError, decode, decode_model, encode
from stream.stages._base import Stage


class CompensationService(Stage):
    """Answers compensation queries for one robot with the latest received model."""

    name = "compensation"

    def __init__(
        self,
        session: zenoh.Session,
        cell: str,
        robot: str,
        robot_model: RobotModel,
        cfg: CompensationConfig,
        logger: JsonLogger | None = None,
    ) -> None:
        super().__init__(session, cell, robot, logger)
        self.robot_model, self.cfg = robot_model, cfg
        self.model: ErrorModel | None = None
        self.version = -1
        self._lock = threading.Lock()
        self.subscribe("model")
        for reply in session.get(self.key("model"), timeout=2.0):
            if reply.ok is not None:
                self._install(reply.ok.payload.to_bytes())
        self.answer("compensate", self._reply)

    def handle(self, item: Received) -> None:
        self._install(item.payload)

    def _install(self, payload: bytes) -> None:
        header, snap = decode_model(payload)
        if header.model_version <= self.version:
            return
        try:
            model = snapshot_from_bytes(snap)
        except Exception as exc:
            raise RejectedMessageError("snapshot", str(exc)) from None
        with self._lock:
            self.model, self.version = model, header.model_version
        self.counter.accept()

    def _reply(self, query: zenoh.Query) -> None:
        with self._lock:
            model, version = self.model, self.version
        if model is None:
            raise RejectedMessageError("no_model", "no model received yet")
        if query.payload is None:
            raise RejectedMessageError("malformed", "compensate query needs a request payload")
        try:
            req = decode(query.payload.to_bytes(), CompensationRequest)
            n = self.robot_model.description.n_joints
            if len(req.q) != n:
                raise RejectedMessageError("joint_count", f"q has {len(req.q)} joints, robot {n}")
        except RejectedMessageError as exc:
            self.counter.drop(exc.reason)
            raise
        reply = compensate(model, self.robot_model, req, self.cfg, version)
        query.reply(self.key("compensate"), encode(reply))
