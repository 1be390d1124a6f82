"""``robocal demo``: the simulated reference cell streamed through the whole pipeline.

The sim ``paper`` campaign (Fanuc M-900iB/700, every effect) is streamed by a
:class:`~stream.sources.SimCellSource` over a loopback Zenoh link into a daemon running the
window, learner (training in a child process of its own), compensation, dashboard and recorder
stages. Every tenth point is held out by the learner stage; the demo reports the uncalibrated
error and the learned model's error on those held-out points (the newest model fetched by
query), and asks the compensation service for corrected commands of held-out poses, scored on
the simulator's true robot. It writes ``robocal.rrd``, ``robocal.mcap`` (or the next free
``robocal.N.*``: recordings are never overwritten) and the JSON-lines log ``robocal.log.jsonl``
into ``out``, and reports the paths it wrote.
"""

from __future__ import annotations

import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np
import torch
import zenoh

from kinematics.dataset import Dataset, temperature_columns, temperature_name
from kinematics.errors import ConfigError
from kinematics.model import RobotModel
from kinematics.transforms import pose_error
from learner.metrics import accuracy_report
from learner.snapshot import snapshot_from_bytes
from sim_sources.cell import SimulatedCell, simulate
from sim_sources.scenarios import get_scenario
from sim_sources.streaming import StreamingConfig
from stream.bus import BusConfig, free_port, open_session
from stream.compensation import CompensationReply, CompensationRequest
from stream.config import DaemonConfig, DashboardConfig, RecorderConfig, RobotConfig
from stream.daemon import Daemon
from stream.learner_core import LearnerStageConfig
from stream.log import JsonLogger
from stream.sources import SimCellSource
from stream.window import WindowConfig
from wire import decode, decode_model, encode, key

# The production example's learner (deploy/robocal.example.toml): the library defaults with a
# memory large enough for the continual model to match batch training.
DEMO_LEARNER = LearnerStageConfig()
REACHED_M = 1e-6  # a corrected command whose solver residual is below this reaches its target


@dataclass(frozen=True, kw_only=True)
class DemoResult:
    """What the demo measured (mm) and where it wrote its files."""

    n_points: int
    n_test: int
    model_version: int
    uncalibrated_mean_mm: float
    uncalibrated_max_mm: float
    learned: dict
    compensation: dict
    samples_published: int
    dropped: dict
    elapsed_s: float
    rrd: str
    mcap: str


def demo_config(out: Path, cell: str, robot: str, T_W_0: np.ndarray, port: int) -> DaemonConfig:
    """The daemon config the demo runs: every stage, loopback bus, files in ``out``."""
    return DaemonConfig(
        cell=cell,
        bus=BusConfig.loopback(port, listen=True),
        robots=(
            RobotConfig(
                name=robot,
                description=robot,
                stages=("window", "learner", "compensation", "dashboard"),
                T_W_0=tuple(map(tuple, T_W_0.tolist())),
            ),
        ),
        window=WindowConfig(batch_size=DEMO_LEARNER.continual.batch),
        learner=DEMO_LEARNER,
        dashboard=DashboardConfig(rrd=str(out / "robocal.rrd")),
        recorder=RecorderConfig(path=str(out / "robocal.mcap")),
    )


def compensation_check(
    session: zenoh.Session,
    cell: str,
    ds: Dataset,
    seed: int,
    rows: np.ndarray,
    policy: str = "flag",
) -> dict:
    """Ask the compensation service for the corrected commands of held-out poses ``rows`` and
    score them on the simulator's true robot: position error (mm) before and after, and after
    for the commands whose solver reached the target (within ``REACHED_M``); near a singular
    pose the rest are answered by the service's ``policy`` (how many, how many untrusted, the
    largest residual left, mm)."""
    sim = SimulatedCell(get_scenario("paper"), len(ds), seed)
    cond = sim.conditions(rows)
    target = RobotModel(sim.model.description).fk(cond.q)
    q_corrected, residual, trusted, policies = [], [], 0, []
    for i in rows:
        temps = {
            temperature_name(c): float(ds.table[c].iloc[i]) for c in temperature_columns(ds.table)
        }
        req = CompensationRequest(
            q=tuple(ds.q()[i]), temperatures=temps, deflection=tuple(ds.deflection()[i])
        )
        replies = list(
            session.get(key(cell, ds.meta.robot, "compensate"), payload=encode(req), timeout=5.0)
        )
        reply = decode(replies[0].ok.payload.to_bytes(), CompensationReply)
        q_corrected.append(reply.q_corrected)
        residual.append(reply.residual_m)
        trusted += reply.trusted
        if reply.policy != "none":  # the solver could not land it: the configured policy
            policies.append((reply.trusted, reply.residual_m))
    before = np.linalg.norm(pose_error(sim.truth.poses(cond), target)[:, :3], axis=1)
    cond_after = replace(cond, q=np.array(q_corrected))
    after = np.linalg.norm(pose_error(sim.truth.poses(cond_after), target)[:, :3], axis=1)
    reached = np.array(residual) < REACHED_M
    return {
        "n": len(rows),
        "before_mean_mm": float(before.mean() * 1e3),
        "after_mean_mm": float(after.mean() * 1e3),
        "reached": int(reached.sum()),
        "reached_after_mean_mm": float(after[reached].mean() * 1e3) if reached.any() else None,
        "max_residual_mm": float(max(residual) * 1e3),
        "trusted_fraction": trusted / len(rows),
        "policy": {
            "name": policy,
            "applied": len(policies),
            "untrusted": sum(not t for t, _ in policies),
            "max_residual_mm": max((r * 1e3 for _, r in policies), default=0.0),
        },
    }


def run_demo(
    out: str | Path = "out",
    n: int = 3004,
    seed: int = 0,
    progress: Callable[[int], None] | None = None,
    logger: JsonLogger | None = None,
    learner: LearnerStageConfig = DEMO_LEARNER,
    period_s: float = 0.6,
    settle_s: float = 0.3,
    serve: bool = False,
) -> DemoResult:
    """Stream an ``n``-point sim campaign through the pipeline; accuracy on held-out points.

    ``progress(k)`` is called with the number of data points the window has emitted so far;
    ``learner`` and ``period_s`` (s between visits) make short runs for tests; the default
    re-times the campaign to a visit every 0.6 s (0.3 s settled; 230,196 samples at 125 Hz joint
    sampling), published as fast as the pipeline takes them: about 50 s on two cores. The
    learner then works through the batches queued behind its updates (the whole demo: 1 min 39 s
    to 2 min 29 s on 2-core VMs, BENCHMARKS.md). ``serve`` also serves the live dashboard
    (``DashboardConfig`` ports; its URL: ``stream.dashboard.viewer_url``).
    """
    if n < 2 * learner.continual.init:
        raise ConfigError(f"demo needs n >= {2 * learner.continual.init} points, got {n}")
    torch.manual_seed(seed)
    start = time.perf_counter()
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    ds = simulate(get_scenario("paper"), n, seed)
    robot, cell = ds.meta.robot, "demo"
    port = free_port()
    cfg = demo_config(out, cell, robot, np.asarray(ds.meta.T_W_0), port)
    cfg = replace(
        cfg,
        learner=replace(learner, seed=seed),
        window=replace(cfg.window, batch_size=learner.continual.batch),
        dashboard=replace(cfg.dashboard, serve=serve),
    )
    log_file = None
    if logger is None:
        log_file = (out / "robocal.log.jsonl").open("w")
        logger = JsonLogger(stream=log_file)
    daemon = Daemon(cfg, logger=logger).start()
    source_session = open_session(BusConfig.loopback(port, listen=False))
    try:
        source = SimCellSource(
            source_session, cell, robot, ds, StreamingConfig(period_s=period_s, settle_s=settle_s)
        )
        thread = threading.Thread(target=source.start, name="demo-source", daemon=True)
        thread.start()
        while thread.is_alive():
            thread.join(0.2)
            if progress is not None:
                progress(daemon.windows[robot].points)
        daemon.end_of_stream({robot: source.published})
        if progress is not None:
            progress(daemon.windows[robot].points)
        replies = list(source_session.get(key(cell, robot, "model"), timeout=5.0))
        payload = next(r.ok.payload.to_bytes() for r in replies if r.ok is not None)
        header, snap = decode_model(payload)
        model = snapshot_from_bytes(snap)
        core = daemon.learners[robot].core
        report = accuracy_report(model, core.test_x, core.test_y)
        rows = np.arange(9, n, 10)[:50]
        compensation = compensation_check(
            source_session, cell, ds, seed, rows, cfg.compensation.policy
        )
        dropped = dict(daemon.windows[robot].counter.dropped)
    finally:
        source_session.close()
        daemon.stop()
        if log_file is not None:
            log_file.close()
    err0 = np.linalg.norm(core.test_y[:, :3], axis=1) * 1e3
    return DemoResult(
        n_points=n,
        n_test=len(core.test_y),
        model_version=header.model_version,
        uncalibrated_mean_mm=float(err0.mean()),
        uncalibrated_max_mm=float(err0.max()),
        learned=report.to_dict(),
        compensation=compensation,
        samples_published=source.published,
        dropped=dropped,
        elapsed_s=time.perf_counter() - start,
        rrd=daemon.recordings.get(f"rrd/{robot}", str(out / "robocal.rrd")),
        mcap=daemon.recordings.get("mcap", str(out / "robocal.mcap")),
    )
