"""What the learner CLI commands write: model snapshots, continual states, learning curves
and the reference study's tables and plot (the workflows in ``learner`` return values).
"""

from __future__ import annotations

import json
from dataclasses import asdict
from pathlib import Path

from learner.continual_state import state_path, state_to_bytes
from learner.experiment import StudyResult
from learner.snapshot import atomic_write_bytes, save_snapshot
from learner.workflow import ContinualResult, TrainResult
from stream.reports.plots import plot_sizes, write_learning_curve


def write_trained(result: TrainResult, out: str | Path) -> Path:
    """Save a batch-trained model to ``out`` and its continual state (the worst-predicted
    training points as memory) beside it, so ``continual --from`` goes on."""
    meta = {"n_train": result.n_train, "epochs": result.report.epochs}
    path = save_snapshot(result.model, out, meta)
    atomic_write_bytes(state_path(out), state_to_bytes(result.learner.state_dict()))
    return path


def curve_paths(out: str | Path) -> tuple[Path, Path]:
    """The learning-curve CSV and PNG written beside a model file."""
    stem = Path(out).with_suffix("")
    return stem.with_name(stem.name + ".curve.csv"), stem.with_name(stem.name + ".curve.png")


def write_continual(result: ContinualResult, out: str | Path) -> tuple[Path, Path]:
    """Save the final model to ``out``, the learner's state (memory included) and the learning
    curve (CSV + PNG) beside it; the curve's paths."""
    learner, cfg = result.learner, result.learner.cfg
    save_snapshot(result.model, out, {"strategy": cfg.strategy, "n_seen": learner.n_seen})
    atomic_write_bytes(state_path(out), state_to_bytes(learner.state_dict()))
    paths = curve_paths(out)
    write_learning_curve(result.curve, paths, f"{cfg.strategy}: N_m={cfg.memory}, n_B={cfg.batch}")
    return paths


def write_study(study: StudyResult, out_dir: str | Path) -> Path:
    """Write ``study.json`` (config and rows), ``study.md`` and ``size.png`` into ``out_dir``."""
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    table = {"config": asdict(study.config), "rows": study.rows}
    (out_dir / "study.json").write_text(json.dumps(table, indent=1))
    (out_dir / "study.md").write_text(study.markdown + "\n")
    plot_sizes(study.rows, out_dir / "size.png")
    return out_dir
