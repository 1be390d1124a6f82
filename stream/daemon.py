"""The daemon: composes the configured stages of every robot on one Zenoh session.

It implements no stage itself. ``start()`` opens the session (or uses the one given) and the
stages in data-flow order (recorder first, so it sees everything); ``stop()`` closes them in
the same order after each has handled what it received: the window sends its partial batch,
the learner writes its checkpoint, the dashboard flushes, the recorder finishes the MCAP file.
:func:`run_until_signal` runs until SIGTERM or SIGINT.
"""

from __future__ import annotations

import signal
import threading
import time
from pathlib import Path

import numpy as np
import torch
import zenoh

from kinematics.description import load_description
from kinematics.model import RobotModel
from stream.bus import open_session
from stream.config import DaemonConfig, RobotConfig
from stream.dashboard import Dashboard
from stream.log import JsonLogger
from stream.stages import (
    CompensationService,
    DashboardStage,
    LearnerStage,
    RecorderStage,
    Stage,
    WindowStage,
)


class Daemon:
    """The stages of ``cfg`` for every robot; ``start()``, then ``stop()``."""

    def __init__(
        self,
        cfg: DaemonConfig,
        session: zenoh.Session | None = None,
        logger: JsonLogger | None = None,
    ) -> None:
        self.cfg = cfg
        self.log = logger or JsonLogger(per_s=cfg.log_per_s)
        self._own_session = session is None
        self.session = session
        self.stages: list[Stage] = []
        self.windows: dict[str, WindowStage] = {}
        self.learners: dict[str, LearnerStage] = {}
        self.dashboards: dict[str, Dashboard] = {}

    def start(self) -> Daemon:
        cfg = self.cfg
        # Small MLPs train fastest on one thread; more threads spin against the stages' threads.
        torch.set_num_threads(cfg.torch_threads)
        if self.session is None:
            self.session = open_session(cfg.bus)
        if cfg.recorder is not None:
            self.stages.append(
                RecorderStage(
                    self.session,
                    cfg.cell,
                    cfg.recorder.path,
                    cfg.recorder.flush_interval_s,
                    self.log,
                )
            )
        for robot in cfg.robots:
            self._start_robot(robot)
        self.log.info("daemon_started", cell=cfg.cell, stages=[s.name for s in self.stages])
        return self

    def _start_robot(self, rc: RobotConfig) -> None:
        cfg, s = self.cfg, self.session
        desc = load_description(rc.description)
        T_W_0 = None if rc.T_W_0 is None else np.asarray(rc.T_W_0, dtype=float)
        if "window" in rc.stages:
            self.windows[rc.name] = WindowStage(s, cfg.cell, rc.name, cfg.window, self.log)
            self.stages.append(self.windows[rc.name])
        if "learner" in rc.stages:
            ckpt = None
            if cfg.checkpoint_dir is not None:
                ckpt = Path(cfg.checkpoint_dir) / f"{rc.name}.checkpoint.safetensors"
            stage = LearnerStage(s, cfg.cell, rc.name, desc, cfg.learner, T_W_0, ckpt, self.log)
            self.learners[rc.name] = stage
            self.stages.append(stage)
        if "compensation" in rc.stages:
            self.stages.append(
                CompensationService(
                    s, cfg.cell, rc.name, RobotModel(desc), cfg.compensation, self.log
                )
            )
        if "dashboard" in rc.stages:
            self.stages.append(self._dashboard_stage(rc, desc, T_W_0))

    def _dashboard_stage(self, rc: RobotConfig, desc, T_W_0) -> DashboardStage:
        dc = self.cfg.dashboard
        dash = Dashboard(RobotModel(desc), recording_id=f"{self.cfg.cell}/{rc.name}")
        if dc.rrd:
            rrd = Path(dc.rrd)
            if len(self.cfg.robots) > 1:
                rrd = rrd.with_name(f"{rrd.stem}_{rc.name}{rrd.suffix}")
            dash.save(rrd)
        if dc.serve:
            self.log.info("dashboard_served", url=dash.serve(dc.web_port, dc.grpc_port))
        if dc.connect:
            dash.connect(dc.connect)
        self.dashboards[rc.name] = dash
        return DashboardStage(
            self.session, self.cfg.cell, rc.name, dash, RobotModel(desc), T_W_0, self.log
        )

    def end_of_stream(
        self, expected: dict[str, int] | None = None, timeout_s: float = 600.0
    ) -> None:
        """For finite runs (demo, replay): once each window has received the ``expected``
        number of samples (per robot; messages may still be in flight), flush the windows and
        let every stage catch up."""
        deadline = time.monotonic() + timeout_s
        for robot, w in self.windows.items():
            want = (expected or {}).get(robot, 0)
            while w.received < want and time.monotonic() < deadline:
                time.sleep(0.01)
            w.drain(timeout_s)
            w.end_of_stream()
        for stage in self.stages:
            if stage.name != "recorder":
                stage.drain(timeout_s)

    def stop(self) -> None:
        """Close every stage in data-flow order, then the session (if the daemon opened it)."""
        order = ["window", "learner", "compensation", "dashboard", "recorder"]
        for stage in sorted(self.stages, key=lambda st: order.index(st.name)):
            stage.drain()
            if stage.name == "window":
                stage.end_of_stream()
            stage.close()
        for dash in self.dashboards.values():
            dash.close()
        self.log.info("daemon_stopped", suppressed_logs=self.log.suppressed)
        self.stages.clear()
        if self._own_session and self.session is not None:
            self.session.close()
            self.session = None


def run_until_signal(cfg: DaemonConfig, logger: JsonLogger | None = None) -> int:
    """Run the daemon until SIGTERM or SIGINT; stop cleanly; return 0."""
    stop = threading.Event()
    previous = {
        sig: signal.signal(sig, lambda *_: stop.set()) for sig in (signal.SIGTERM, signal.SIGINT)
    }
    daemon = Daemon(cfg, logger=logger).start()
    try:
        while not stop.wait(0.5):
            for stage in daemon.stages:
                if stage.worker.error is not None:
                    raise stage.worker.error
    finally:
        daemon.stop()
        for sig, handler in previous.items():
            signal.signal(sig, handler)
    return 0
