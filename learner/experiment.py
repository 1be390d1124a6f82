"""The reference study of DESIGN.md on one dataset: feature ablation, accuracy against
training-set size, continual (n_B × N_m) against batch, and the sparse GP benchmark.

Returns the rows and their Markdown table (the CLI writes ``study.json``, ``study.md`` and
``size.png``: ``stream.reports.learner``); every run uses the same seeded 90/10 split, so rows
are comparable.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

from kinematics.dataset import Dataset
from kinematics.errors import ConfigError
from learner.config import ContinualConfig, ModelConfig, TrainConfig
from learner.continual import ContinualLearner
from learner.metrics import accuracy_report
from learner.model import ErrorModel
from learner.workflow import prepare

#: name -> (deflections, temperatures, input encoding); the last row is DESIGN.md's plain
#: min-max scaling of every raw feature, to show what the kinematic encoding adds.
ABLATION = {
    "all": (True, True, "kinematic"),
    "joints+deflections": (True, False, "kinematic"),
    "joints+temperatures": (False, True, "kinematic"),
    "joints only": (False, False, "kinematic"),
    "all, min-max inputs": (True, True, "minmax"),
}


@dataclass(frozen=True, kw_only=True)
class StudyConfig:
    """What the study runs; ``quick()`` is a small grid for smoke tests."""

    sizes: tuple[int, ...] = (100, 250, 500, 1000, 2000, 2704)
    repeats: int = 10
    batches: tuple[int, ...] = (10, 50, 100)
    memories: tuple[int, ...] = (200, 500)
    max_epochs: int = 1500
    epochs_per_update: int = ContinualConfig().epochs_per_update
    sgpr: bool = True
    sgpr_iterations: int = 100
    seed: int = 0

    def __post_init__(self) -> None:
        if self.repeats < 1 or not self.sizes or min(self.sizes) < 20:
            raise ConfigError(f"study needs repeats >= 1 and sizes >= 20, got {self.sizes}")

    @classmethod
    def quick(cls, seed: int = 0) -> StudyConfig:
        return cls(
            sizes=(100, 300),
            repeats=2,
            batches=(100,),
            memories=(200,),
            max_epochs=30,
            epochs_per_update=5,
            sgpr=False,
            seed=seed,
        )

    @property
    def n_runs(self) -> int:
        grid = len(self.batches) * len(self.memories)
        return len(ABLATION) + len(self.sizes) * self.repeats + grid + int(self.sgpr)


@dataclass(frozen=True, kw_only=True)
class StudyResult:
    """The study's config, one row per run and the Markdown table of the rows."""

    config: StudyConfig
    rows: list[dict] = field(default_factory=list)
    markdown: str = ""

    def to_dict(self) -> dict:
        return {"rows": self.rows}


def run_paper_study(
    ds: Dataset,
    cfg: StudyConfig,
    on_run: Callable[[str], None] | None = None,
) -> StudyResult:
    """Run every part of the study; its rows and Markdown table."""
    note = on_run or (lambda name: None)
    train_cfg = TrainConfig(max_epochs=cfg.max_epochs, seed=cfg.seed)
    rows: list[dict] = []
    p_all = prepare(ds, seed=cfg.seed)
    Y0 = p_all.Y[p_all.test]

    def batch_row(section, name, p, train_idx, seed, encoding="kinematic"):
        start = time.perf_counter()
        model_cfg = ModelConfig(encoding=encoding)
        model = ErrorModel.create(p.spec, model_cfg, train_cfg, seed, p.robot)
        model.fit(p.X[train_idx], p.Y[train_idx])
        rep = accuracy_report(model, p.X[p.test], p.Y[p.test], Y0)
        row = {
            "section": section,
            "name": name,
            "n_train": len(train_idx),
            "seed": seed,
            "time_s": time.perf_counter() - start,
            **rep.to_dict(),
        }
        note(name)
        return row

    for name, (secondary, temps, encoding) in ABLATION.items():
        p = prepare(ds, seed=cfg.seed, secondary=secondary, temperatures=temps)
        rows.append(batch_row("features", name, p, p.train, cfg.seed, encoding))
    rng = np.random.default_rng(cfg.seed)
    for size in cfg.sizes:
        for r in range(cfg.repeats):
            idx = rng.choice(p_all.train, size=min(size, len(p_all.train)), replace=False)
            rows.append(batch_row("size", f"n={size}", p_all, idx, cfg.seed + r))
    train = np.sort(p_all.train)
    for n_b in cfg.batches:
        for n_m in cfg.memories:
            rows.append(_continual_row(p_all, train, Y0, cfg, train_cfg, n_b, n_m))
            note(f"continual n_B={n_b} N_m={n_m}")
    if cfg.sgpr:
        from learner.sgpr import fit_predict_sgpr

        start = time.perf_counter()
        pred = fit_predict_sgpr(
            p_all.spec,
            p_all.X[p_all.train],
            p_all.Y[p_all.train],
            p_all.X[p_all.test],
            iterations=cfg.sgpr_iterations,
            seed=cfg.seed,
        )
        pos = np.linalg.norm(pred[:, :3] - p_all.Y[p_all.test, :3], axis=1) * 1e3
        rows.append(
            {
                "section": "sgpr",
                "name": "SGPR (gpytorch, 200 inducing)",
                "n_train": len(p_all.train),
                "time_s": time.perf_counter() - start,
                "mean_mm": float(pos.mean()),
                "max_mm": float(pos.max()),
            }
        )
        note("sgpr")
    return StudyResult(config=cfg, rows=rows, markdown=_markdown(rows, cfg))


def _continual_row(p, train, Y0, cfg, train_cfg, n_b, n_m) -> dict:
    model = ErrorModel.create(p.spec, ModelConfig(), train_cfg, cfg.seed, p.robot)
    ccfg = ContinualConfig(
        memory=n_m,
        batch=n_b,
        epochs_per_update=cfg.epochs_per_update,
        init_epochs=min(300, cfg.max_epochs),
        seed=cfg.seed,
    )
    learner = ContinualLearner(model, ccfg)
    start = time.perf_counter()
    for _ in learner.learn_stream(p.X[train], p.Y[train]):
        pass
    rep = accuracy_report(learner.model, p.X[p.test], p.Y[p.test], Y0)
    return {
        "section": "continual",
        "name": f"n_B={n_b}, N_m={n_m}",
        "n_train": len(train),
        "time_s": time.perf_counter() - start,
        **rep.to_dict(),
    }


def _markdown(rows: list[dict], cfg: StudyConfig) -> str:
    lines = [
        "| section | run | n_train | mean mm | max mm | cov 90 | time s |",
        "|---|---|---|---|---|---|---|",
    ]
    groups: dict[tuple[str, str], list[dict]] = {}
    for row in rows:
        groups.setdefault((row["section"], row["name"]), []).append(row)
    for (section, name), rs in groups.items():
        mean = np.array([r["mean_mm"] for r in rs])
        spread = f" ± {mean.std():.4f}" if len(rs) > 1 else ""
        cov = np.mean([r.get("coverage_90", np.nan) for r in rs])
        lines.append(
            f"| {section} | {name} | {rs[0]['n_train']} | {mean.mean():.4f}{spread} | "
            f"{np.mean([r['max_mm'] for r in rs]):.4f} | {cov:.3f} | "
            f"{np.mean([r['time_s'] for r in rs]):.1f} |"
        )
    return "\n".join(lines)
