"""The compensation service: a queryable on ``.../compensate`` using the newest model.

Request payload: JSON of :class:`~stream.compensation.CompensationRequest` (``schema``
``robocal.compensate.request``, ``version``); reply: JSON of
:class:`~stream.compensation.CompensationReply`, or a Zenoh error reply with one line that
starts with its reason (bad request, no model yet). Answers go through
:func:`~stream.compensation_guard.guarded_compensate`: what it cannot stand behind is
``trusted: false`` with a coded reason, and a command the solver cannot land (near a singular
pose) is answered by the configured ``[compensation] policy`` (``refuse``, ``flag`` or
``best_effort`` within ``joint_motion_limit_rad``), named in the reply's ``policy``. The
service follows ``.../model`` and, on start, asks
the ``.../model`` queryable for the latest snapshot; a snapshot is adopted only when
:class:`~stream.trust.ModelGate` says it belongs to this cell (a refusal is counted, logged
once per kind and shown on ``diagnostics``; the last good model stays). Every answer is also
put on ``.../compensate``, where the dashboard draws it.
"""

from __future__ import annotations

import threading

import zenoh

from kinematics.model import RobotModel
from learner.model import ErrorModel
from stream.compensation import CompensationConfig, CompensationRequest
from stream.compensation_guard import GuardConfig, guarded_compensate
from stream.log import JsonLogger
from stream.stages._base import Stage
from stream.trust import ModelGate, ModelTrustConfig
from stream.worker import Received
from wire import RejectedMessageError, decode, encode

#: Reasons of a model not adopted that are logged (``model_old`` is routine, only counted).
LOGGED_REFUSALS = ("model_foreign", "model_version", "snapshot", "malformed", "too_large")


def adopt(stage: Stage, gate: ModelGate, payload: bytes):
    """The gate's verdict on a snapshot for ``stage``: ``(header, model)``, or None after
    counting (and logging once per kind) a refusal."""
    try:
        return gate.admit(payload)
    except RejectedMessageError as exc:
        kind = exc.reason if exc.reason in LOGGED_REFUSALS else "other"
        first = stage.counter.refuse(kind, exc.reason, str(exc)[:300])
        if first and exc.reason != "model_old":
            stage.log.log(
                "warning",
                "model_refused",
                stage=stage.name,
                robot=stage.robot,
                reason=exc.reason,
                detail=str(exc)[:300],
                kept_version=gate.version,
            )
        return None


class CompensationService(Stage):
    """Answers compensation queries for one robot with the latest adopted model."""

    name = "compensation"

    def __init__(
        self,
        session: zenoh.Session,
        cell: str,
        robot: str,
        robot_model: RobotModel,
        cfg: CompensationConfig,
        logger: JsonLogger | None = None,
        trust: ModelTrustConfig | None = None,
        guard: GuardConfig | None = None,
    ) -> None:
        super().__init__(session, cell, robot, logger)
        self.robot_model, self.cfg, self.guard = robot_model, cfg, guard or GuardConfig()
        self.gate = ModelGate(robot, robot_model.description, trust)
        self.model: ErrorModel | None = None
        self.version = -1
        self._lock = threading.Lock()
        self.subscribe("model")
        for reply in session.get(self.key("model"), timeout=2.0):
            if reply.ok is not None:
                payload = reply.ok.payload.to_bytes()
                self.worker.call(lambda p=payload: self._install(p))
        self.answer("compensate", self._reply)

    def handle(self, item: Received) -> None:
        self._install(item.payload)

    def _install(self, payload: bytes) -> None:
        adopted = adopt(self, self.gate, payload)
        if adopted is None:
            return
        header, model = adopted
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
        reply = guarded_compensate(model, self.robot_model, req, self.cfg, version, self.guard)
        payload = encode(reply)
        query.reply(self.key("compensate"), payload)
        self.put("compensate", payload)  # a reply reaches only its asker; watchers see this
