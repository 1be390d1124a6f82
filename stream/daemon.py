"""The daemon: composes the configured stages of every robot on one Zenoh session.

It implements no stage itself. ``start()`` opens the session (or uses the one given) and the
stages in data-flow order (recorder first, so it sees everything); ``stop()`` closes them in
the same order after each has handled what it received: the window sends its partial batch,
the learner writes its checkpoint, the dashboard flushes, the recorder finishes the MCAP file.

:func:`run_until_signal` supervises: it runs until SIGTERM or SIGINT (exit 0) or until a stage
dies (one ``stage_failed`` line naming the stage and the cause; exit 2 for a resource failure
such as a full disk or a read-only state directory, else 1), so that systemd restarts it. It
always ends within ``shutdown_timeout_s`` + 1.5 s: queued work past the timeout is abandoned
(the last checkpoint stands), the MCAP file is finished, and a watchdog ends the process if
anything is still stuck. State directories are proved writable before anything starts.
"""

from __future__ import annotations

import contextlib
import math
import os
import signal
import threading
import time
from dataclasses import replace
from pathlib import Path

import numpy as np
import zenoh

from kinematics.description import load_description
from kinematics.model import RobotModel
from learner.training import set_compute_threads
from stream.bus import BusUnreachableError, open_session
from stream.config import DaemonConfig, RobotConfig, dashboard_index
from stream.dashboard import Dashboard
from stream.learner_core import check_thermometers
from stream.log import JsonLogger
from stream.mcap_io import next_free_path
from stream.sources.build import SourceThread, build_source
from stream.stages import (
    STAGES,
    CompensationService,
    DashboardStage,
    LearnerStage,
    RecorderStage,
    Stage,
    WindowStage,
)
from stream.state import StateDirError, check_writable, describe_os_error

#: How long a stopping learner waits for its window's last batch to be learned before it
#: stops listening (s); once arrived, a batch still queued is learned by the close anyway.
LAST_BATCH_WAIT_S = 5.0

#: Exit codes: a stage died of a resource failure (disk, permissions), or of anything else.
EXIT_RESOURCE, EXIT_STAGE = 2, 1


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
        #: The files this start records into (a new one per start): ``mcap``, ``rrd/<robot>``.
        self.recordings: dict[str, str] = {}
        #: The ``[[sources]]`` this daemon reads itself, each in its thread (started last).
        self.sources: list[SourceThread] = []

    def start(self, until: threading.Event | None = None) -> Daemon:
        """Check the state directories, open the session and the stages; on any failure the
        stages already open are closed again before the error is raised. With ``until``, a
        client whose router is not reachable waits for it (``bus_unreachable`` warnings) until
        the router answers or ``until`` is set (then nothing is started)."""
        cfg = self.cfg
        # Every robot's description first: a missing one stops the start before anything opens.
        self._descriptions = {rc.name: load_description(rc.description) for rc in cfg.robots}
        # Small MLPs train fastest on one thread; more threads spin against the stages' threads.
        set_compute_threads(cfg.torch_threads)
        if cfg.checkpoint_dir is not None:
            check_writable(cfg.checkpoint_dir, "checkpoint_dir")
        if cfg.recorder is not None:
            check_writable(Path(cfg.recorder.path).parent, "recorder directory")
        if cfg.dashboard is not None and cfg.dashboard.rrd:
            check_writable(Path(cfg.dashboard.rrd).parent, "dashboard rrd directory")
        if self.session is None and until is not None:
            self.session = self._wait_for_bus(until)
            if self.session is None:  # stopped while waiting for the router
                return self
        try:
            self._start_stages()
        except BaseException as exc:
            self.stop(timeout_s=5.0)
            if isinstance(exc, OSError):
                raise StateDirError(f"cannot start: {describe_os_error(exc)}") from None
            raise
        return self

    def _wait_for_bus(self, until: threading.Event) -> zenoh.Session | None:
        """Open the bus, retrying every 2 s while the routers are unreachable (a router that
        starts later, or restarts, is not a reason to exit); None once ``until`` is set."""
        last_warning = -math.inf
        while not until.is_set():
            try:
                return open_session(self.cfg.bus)
            except BusUnreachableError as exc:
                if time.monotonic() - last_warning >= 30.0:
                    last_warning = time.monotonic()
                    self.log.log("warning", "bus_unreachable", retry_s=2.0, cause=str(exc)[:300])
            until.wait(2.0)
        return None

    def _start_stages(self) -> None:
        cfg = self.cfg
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
                    split_size_mb=cfg.recorder.split_size_mb,
                    split_interval_s=cfg.recorder.split_interval_s,
                    robots=cfg.robots,
                )
            )
        for robot in cfg.robots:
            self._start_robot(robot)
        for src in self.sources:  # after every stage, so that nothing they publish is missed
            src.start()
        for st in self.stages:
            st.on_disk_full = cfg.on_disk_full
        for st in self.stages:
            if isinstance(st, RecorderStage):
                self.recordings["mcap"] = str(st.recorder.path)
        self.log.info(
            "daemon_started",
            cell=cfg.cell,
            stages=[s.name for s in self.stages],
            recordings=self.recordings,
        )
        self._check_bus_role()

    def _check_bus_role(self) -> None:
        """Warn when the TLS certificate's role may not publish what these stages publish:
        the router would drop it without a word (deploy/zenohd.json5)."""
        if self.cfg.bus.tls is None:
            return
        from stream.security import certificate_name

        name = certificate_name(self.cfg.bus.tls.cert)
        learning = {"window", "learner", "compensation"} & {s.name for s in self.stages}
        if learning and name.split("-")[0] != "learner":
            self.log.log(
                "warning",
                "bus_role",
                certificate=name,
                stages=sorted(learning),
                detail="only the learner role may publish points, batches and models and "
                "answer compensate: the router drops them from this certificate",
            )

    def _start_robot(self, rc: RobotConfig) -> None:
        cfg, s = self.cfg, self.session
        desc = self._descriptions[rc.name]
        T_W_0 = None if rc.T_W_0 is None else np.asarray(rc.T_W_0, dtype=float)
        state = None if cfg.checkpoint_dir is None else Path(cfg.checkpoint_dir)
        if "window" in rc.stages:
            wcfg = replace(cfg.window, n_joints=desc.n_joints)  # the description decides
            self.windows[rc.name] = WindowStage(
                s,
                cfg.cell,
                rc.name,
                wcfg,
                self.log,
                state_path=None if state is None else state / f"{rc.name}.window.json",
            )
            self.stages.append(self.windows[rc.name])
        if "learner" in rc.stages:
            ckpt = None if state is None else state / f"{rc.name}.checkpoint.safetensors"
            start_from, pinned = cfg.learner.start_from, cfg.window.temperature_names
            if start_from and pinned and not (ckpt is not None and ckpt.exists()):
                check_thermometers(start_from, pinned)
            stage = LearnerStage(s, cfg.cell, rc.name, desc, cfg.learner, T_W_0, ckpt, self.log)
            self.learners[rc.name] = stage
            self.stages.append(stage)
        if "compensation" in rc.stages:
            self.stages.append(
                CompensationService(
                    s,
                    cfg.cell,
                    rc.name,
                    RobotModel(desc),
                    cfg.compensation,
                    self.log,
                    trust=cfg.models,
                )
            )
        if "dashboard" in rc.stages:
            self.stages.append(self._dashboard_stage(rc, desc, T_W_0))
        for sc in cfg.sources:
            if (sc.robot or cfg.robots[0].name) == rc.name:
                source = build_source(sc, s, cfg.cell, rc.name, desc)
                self.sources.append(SourceThread(source, self.log))

    def _dashboard_stage(self, rc: RobotConfig, desc, T_W_0) -> DashboardStage:
        dc = self.cfg.dashboard
        dash = Dashboard(RobotModel(desc), recording_id=f"{self.cfg.cell}/{rc.name}")
        rrd = served = None
        if dc.rrd:
            rrd = Path(dc.rrd)
            if len(self.cfg.robots) > 1:
                rrd = rrd.with_name(f"{rrd.stem}_{rc.name}{rrd.suffix}")
            rrd = next_free_path(rrd)  # never overwrite an earlier run's recording
            self.recordings[f"rrd/{rc.name}"] = str(rrd)
        if dc.serve:
            i = dashboard_index(self.cfg, rc.name)  # each robot its own ports: none collide
            served = (dc.web_port + i, dc.grpc_port + i, dc.host)
        url = dash.open(rrd, served, dc.connect or None)  # all sinks at once (rerun replaces)
        if url is not None:
            self.log.info("dashboard_served", robot=rc.name, url=url)
        self.dashboards[rc.name] = dash
        return DashboardStage(
            self.session,
            self.cfg.cell,
            rc.name,
            dash,
            RobotModel(desc),
            T_W_0,
            self.log,
            trust=self.cfg.models,
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

    def counts(self) -> dict[str, dict]:
        """The end-of-run summary: accepted and dropped (by reason) per ``stage/robot``."""
        out = {}
        for st in self.stages:
            st.count_worker_drops()
            c = st.counter
            out[f"{st.name}/{st.robot}"] = {"accepted": c.accepted, "dropped": dict(c.dropped)}
        return out

    def failed_stage(self) -> Stage | None:
        """The first stage whose worker died, or None."""
        return next((st for st in [*self.sources, *self.stages] if st.failure is not None), None)

    def stop(self, timeout_s: float = 600.0) -> dict[str, BaseException]:
        """Close every stage in data-flow order within ``timeout_s`` (queued work past it is
        abandoned), then the session (if the daemon opened it). Never raises: returns the
        fatal errors by stage (``name/robot``)."""
        deadline = time.monotonic() + timeout_s
        reserve = min(2.0, timeout_s / 4)  # kept for the stages after the learner
        order = list(STAGES)  # the registry's data-flow order, the recorder last
        failures: dict[str, BaseException] = {}
        for src in self.sources:  # first: what they published is still worked off below
            error = src.close(timeout_s=min(5.0, timeout_s / 4))
            if error is not None:
                failures[f"{src.name}/{src.robot}"] = error
        self.sources.clear()
        for stage in self.stages:  # nothing new comes in while the queues are worked off; a
            if not isinstance(stage, LearnerStage):  # learner hears its window's last batch
                stage.unsubscribe()
        sent: dict[str, tuple[int, int]] = {}  # robot -> its window's last batch
        for stage in sorted(self.stages, key=lambda st: order.index(st.name)):
            keep = 0.0 if stage.name == "recorder" else reserve
            left = max(deadline - time.monotonic() - keep, 0.5)
            if isinstance(stage, WindowStage) and stage.failure is None:
                try:  # a backlog past the timeout: the partial batch stays in the window state
                    if stage.drain(left):
                        stage.end_of_stream(timeout_s=max(deadline - time.monotonic() - keep, 0.5))
                except Exception as exc:  # noqa: BLE001 - reported, the others still close
                    failures[f"{stage.name}/{stage.robot}"] = exc
                if stage.last_batch is not None:
                    sent[stage.robot] = stage.last_batch
            if isinstance(stage, LearnerStage) and stage.robot in sent:
                last = sent[stage.robot]  # the bus delivers it on another thread: wait for it
                until = time.monotonic() + min(left, LAST_BATCH_WAIT_S)
                while not stage.has_learned(*last) and time.monotonic() < until:
                    time.sleep(0.01)
            error = stage.close(timeout_s=max(deadline - time.monotonic() - keep, 0.5))
            if error is not None:
                failures[f"{stage.name}/{stage.robot}"] = error
        for dash in self.dashboards.values():
            try:
                dash.close()
            except Exception as exc:  # noqa: BLE001
                failures["dashboard"] = exc
        self.log.info("daemon_stopped", suppressed_logs=self.log.suppressed, counts=self.counts())
        self.stages.clear()
        if self._own_session and self.session is not None:
            with contextlib.suppress(Exception):
                self.session.close()
            self.session = None
        return failures


def exit_code(error: BaseException) -> int:
    """2 for a resource failure (OSError, StateDirError, MemoryError), 1 for anything else."""
    return EXIT_RESOURCE if isinstance(error, OSError | StateDirError | MemoryError) else EXIT_STAGE


def cause(error: BaseException) -> str:
    """One line for a stage's fatal error."""
    if isinstance(error, OSError):
        return describe_os_error(error)
    return f"{type(error).__name__}: {error}"[:300]


def _watchdog(log: JsonLogger, after_s: float, code: list[int]) -> threading.Event:
    """End the process with ``code[0]`` (1 if 0) unless the returned event is set in time."""
    done = threading.Event()

    def watch() -> None:
        if not done.wait(after_s):
            log.log("error", "shutdown_timeout", after_s=after_s)
            os._exit(code[0] or EXIT_STAGE)

    threading.Thread(target=watch, name="shutdown-watchdog", daemon=True).start()
    return done


def run_until_signal(cfg: DaemonConfig, logger: JsonLogger | None = None) -> int:
    """Run the daemon until SIGTERM or SIGINT (0) or a stage's death (1, or 2 for a resource
    failure); always stop within ``cfg.shutdown_timeout_s`` + 1.5 s."""
    stop = threading.Event()
    previous = {
        sig: signal.signal(sig, lambda *_: stop.set()) for sig in (signal.SIGTERM, signal.SIGINT)
    }
    daemon = Daemon(cfg, logger=logger)
    log = daemon.log
    code = [0]
    try:
        daemon.start(until=stop)  # a failure here has closed what it opened: one line
    except BaseException:
        for sig, handler in previous.items():
            signal.signal(sig, handler)
        raise
    try:
        while not stop.wait(0.2):
            failed = daemon.failed_stage()
            if failed is not None:
                code[0] = exit_code(failed.failure)
                log.log(
                    "error",
                    "stage_failed",
                    stage=failed.name,
                    robot=failed.robot,
                    cause=cause(failed.failure),
                )
                break
    finally:
        if stop.is_set():
            log.info("signal_received")
        _watchdog(log, cfg.shutdown_timeout_s + 1.5, code)  # lives until the process ends
        failures = daemon.stop(timeout_s=cfg.shutdown_timeout_s)
        for sig, handler in previous.items():
            signal.signal(sig, handler)
    for where, error in failures.items():
        if code[0] == 0:
            code[0] = exit_code(error)
            log.log("error", "stage_failed", stage=where, cause=cause(error))
    return code[0]
