"""The gap report: Markdown with tables, matplotlib PNG plots and a Rerun ``.rrd`` recording.

The recording holds, per stage (timeline ``stage``), the held-out tool positions coloured by
residual and the residual vectors (exaggerated ``ARROW_GAIN`` times, in the base frame), and
the held-out mean residual as a scalar; open it with ``rerun gap.rrd``.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from kinematics.calibration import CalibrationResult
from kinematics.gap.model_file import ModelFile, model_to_toml
from kinematics.gap.workflow import GapResult
from stream.reports.plots import new_figure, save_figure

ARROW_GAIN = 200.0


@dataclass(frozen=True, kw_only=True)
class ReportFiles:
    """Paths of what :func:`write_report` wrote."""

    markdown: Path
    plots: tuple[Path, ...]
    recording: Path
    model: Path


def write_report(result: GapResult, out_dir: str | Path) -> ReportFiles:
    """Write ``gap.md``, ``gap_*.png``, ``gap.rrd`` and ``model.toml`` into ``out_dir``."""
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    plots = (_plot_stages(result, out / "gap_stages.png"), _plot_regions(result, out))
    model = out / "model.toml"
    model.write_text(model_to_toml(result.model_file()))
    recording = _record(result, out / "gap.rrd")
    markdown = out / "gap.md"
    markdown.write_text(markdown_text(result, [p.name for p in plots]))
    return ReportFiles(markdown=markdown, plots=plots, recording=recording, model=model)


def write_calibrated_model(result: CalibrationResult, path: str | Path) -> Path:
    """Write the calibrated model (description + ``T_W_0``, no effects) as a model-file TOML."""
    model = ModelFile(description=result.description, T_W_0=result.T_W_0, effects=())
    path = Path(path)
    path.write_text(model_to_toml(model))
    return path


def markdown_text(result: GapResult, plot_names: list[str] = ()) -> str:
    """The Markdown report of ``result``."""
    floor = result.noise_floor.mean_m * 1e3
    lines = [
        f"# Sim-vs-measured gap: {result.robot} (start: {result.start})",
        "",
        f"Noise floor: {floor:.4f} mm mean position error ({result.noise_floor.source}).",
        "",
        "## Held-out residual per stage",
        "",
        "| stage | mean mm | RMS mm | max mm | mean / floor | mean arcmin |",
        "|---|---|---|---|---|---|",
    ]
    for s in result.stages:
        h = s.heldout
        lines.append(
            f"| {s.label} | {h.mean_mm:.4f} | {h.rms_mm:.4f} | {h.max_mm:.4f} | "
            f"{h.mean_mm / floor:.2f} | {h.mean_arcmin:.3f} |"
        )
    lines += ["", "## Named effects", ""]
    if not result.named:
        lines.append("None: no candidate explains a significant part of the residual.")
    for e in result.named:
        ev = e.evidence
        lines += [
            f"### {e.effect}" if e.identified else f"### unnamed correction ({e.effect} shape)",
            "",
            f"{e.message[0].upper()}{e.message[1:]}; parameter std inflation {e.inflation:.3g}, "
            f"largest |value| / std {e.value_to_std:.3g}.",
            "",
            f"Explains {100 * ev.explained_share:.1f}% of the residual; F = {ev.f_stat:.1f}, "
            f"Holm p = {ev.p_holm:.2e}, dBIC = {ev.delta_bic:.1f}; "
            f"{len(ev.kept)} of {ev.n_parameters} parameters identifiable; "
            f"joint refit condition number {e.fit_condition_number:.3g}"
            + (f" (absorbed by the model: {', '.join(ev.absorbed)})" if ev.absorbed else "")
            + ".",
            "",
            "| parameter | value | std |",
            "|---|---|---|",
            *(f"| {k} | {v:.6g} | {e.std[k]:.3g} |" for k, v in e.parameters.items()),
            "",
        ]
    lines += ["", "## Candidates in the last round", ""]
    lines += ["| effect | share | F | Holm p | dBIC | note |", "|---|---|---|---|---|---|"]
    for c in result.last_candidates:
        lines.append(
            f"| {c.effect} | {100 * c.explained_share:.2f}% | {c.f_stat:.2f} | "
            f"{c.p_holm:.3g} | {c.delta_bic:.1f} | {c.note} |"
        )
    lines += ["", "## Candidates not formed", ""]
    lines += [f"- {name}: {why}" for name, why in result.not_formed] or ["None."]
    lines += ["", "## Regions (held-out), before and after", ""]
    lines += ["| family | region | n | before mm | after mm | floor ratio after | flagged after |"]
    lines.append("|---|---|---|---|---|---|---|")
    for b, a in zip(result.stages[0].regions, result.stages[-1].regions, strict=True):
        lines.append(
            f"| {b.family} | {b.region} | {b.n} | {b.mean_mm:.4f} | {a.mean_mm:.4f} | "
            f"{a.ratio_to_floor:.2f} | {'yes' if a.significant else 'no'} |"
        )
    lines += ["", "## Notes", "", *(f"- {n}" for n in result.notes)]
    lines.append(
        f"- Residual consistent with the noise floor: "
        f"{'yes' if result.consistent_with_floor else 'no'}."
    )
    lines += ["", *(f"![{n}]({n})" for n in plot_names), ""]
    return "\n".join(lines)


def _plot_stages(result: GapResult, path: Path) -> Path:
    fig, ax = new_figure((7, 4))
    labels = [s.label for s in result.stages]
    x = np.arange(len(labels))
    ax.bar(x - 0.2, [s.heldout.mean_mm for s in result.stages], 0.4, label="mean")
    ax.bar(x + 0.2, [s.heldout.rms_mm for s in result.stages], 0.4, label="RMS")
    ax.axhline(result.noise_floor.mean_m * 1e3, color="k", ls="--", label="noise floor")
    ax.set_xticks(x, labels)
    ax.set_yscale("log")
    ax.set_ylabel("held-out position residual (mm)")
    ax.legend()
    return save_figure(fig, path)


def _plot_regions(result: GapResult, out: Path) -> Path:
    path = out / "gap_regions.png"
    before, after = result.stages[0].regions, result.stages[-1].regions
    fig, ax = new_figure((8, max(4, 0.18 * len(before))))
    y = np.arange(len(before))
    ax.barh(y + 0.2, [r.ratio_to_floor for r in before], 0.4, label=result.stages[0].label)
    ax.barh(y - 0.2, [r.ratio_to_floor for r in after], 0.4, label=result.stages[-1].label)
    ax.axvline(1.0, color="k", ls="--", label="noise floor")
    ax.set_yticks(y, [r.region for r in before], fontsize=6)
    ax.set_xscale("log")
    ax.set_xlabel("held-out mean residual / noise floor")
    ax.legend()
    return save_figure(fig, path)


def _record(result: GapResult, path: Path) -> Path:
    import rerun as rr

    rec = rr.RecordingStream("robocal_gap")
    rec.save(path)
    xyz = result.heldout_xyz_m
    top = max(float(np.linalg.norm(result.stages[0].residual_m, axis=1).max()), 1e-12)
    for k, stage in enumerate(result.stages):
        rec.set_time("stage", sequence=k)
        norm = np.linalg.norm(stage.residual_m, axis=1) / top
        colors = np.c_[255 * norm, 80 + 0 * norm, 255 * (1 - norm)].astype(np.uint8)
        rec.log("gap/heldout", rr.Points3D(xyz, colors=colors, radii=0.01))
        rec.log(
            "gap/residual",
            rr.Arrows3D(vectors=ARROW_GAIN * stage.residual_m, origins=xyz, colors=colors),
        )
        rec.log("gap/mean_mm", rr.Scalars(stage.heldout.mean_mm))
        rec.log("gap/noise_floor_mm", rr.Scalars(result.noise_floor.mean_m * 1e3))
    rec.flush()
    rec.disconnect()
    return path
