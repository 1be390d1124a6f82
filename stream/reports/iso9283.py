"""The ISO 9283 report of a dataset: AP/RP per repeated pose (and AD/RD where the program has
commanded distances), before and after compensation, as a value, Markdown and a PNG.

Rows that command the same joint angles (within a tolerance) are one test pose and its cycles
(:func:`kinematics.iso9283.group_repeated`). *Before compensation* the attained pose is the
measured one and the commanded pose is the nominal model's at the commanded joints (the
label of DESIGN.md, ``e``); *after compensation* the attained pose is what is left of the
measured error once the model's predicted error at that command is taken away,
``e - ErrorModel.predict(x).mean``: the pose a command corrected by that prediction attains, to
first order. Positions in mm, orientations in degrees (ISO 9283 clause 4). A dataset of the
simulator's ISO 9283 cube program (``robocal sim dataset --scenario iso9283``) names its poses
P1-P5 in its metadata, and its P2-P4 pair gives the distance characteristics (clause 7.4).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from kinematics.dataset import Dataset
from kinematics.errors import DatasetError
from kinematics.iso9283 import (
    STANDARD_CYCLES,
    DistanceCharacteristics,
    PoseCharacteristics,
    distance_characteristics,
    group_repeated,
    pose_characteristics,
)
from kinematics.model import RobotModel
from learner.model import ErrorModel
from learner.workflow import nominal_description, prepare
from stream.reports.plots import new_figure, save_figure

#: Commanded joint angles closer than this in every joint (rad) are the same test pose.
POSE_TOLERANCE_RAD = 1e-4
DISTANCE_POSES = ("P2", "P4")  # ISO 9283 clause 7.4: the distance between P2 and P4


@dataclass(frozen=True)
class PoseResult:
    """One test pose: its name, rows, commanded joints (rad) and position (mm), and its AP/RP
    before and (with a model) after compensation."""

    name: str
    rows: np.ndarray
    q: np.ndarray
    commanded_mm: np.ndarray
    before: PoseCharacteristics
    after: PoseCharacteristics | None

    def to_dict(self) -> dict:
        return {
            "pose": self.name,
            "n": int(self.rows.size),
            "q_rad": self.q.tolist(),
            "commanded_mm": self.commanded_mm.tolist(),
            "before": self.before.to_dict(),
            "after": None if self.after is None else self.after.to_dict(),
        }


@dataclass(frozen=True)
class IsoReport:
    """The report's values: the poses, the distance characteristics when the program has them
    (``{"poses": [...], "before": ..., "after": ...}``) and notes on what it could not do."""

    data: str
    model: str | None
    n_rows: int
    poses: list[PoseResult]
    distance: dict | None
    notes: list[str] = field(default_factory=list)

    def summary(self, which: str) -> dict | None:
        """The worst pose's AP_P and RP_l (mm) ``before`` or ``after`` compensation."""
        values = [getattr(p, which) for p in self.poses]
        if any(v is None for v in values):
            return None
        return {
            "ap_p_max_mm": max(v.ap_p_mm for v in values),
            "ap_p_mean_mm": float(np.mean([v.ap_p_mm for v in values])),
            "rp_l_max_mm": max(v.rp_l_mm for v in values),
        }

    def to_dict(self) -> dict:
        dist = None
        if self.distance is not None:
            after = self.distance["after"]
            dist = {
                "poses": list(self.distance["poses"]),
                "before": self.distance["before"].to_dict(),
                "after": None if after is None else after.to_dict(),
            }
        return {
            "standard": "ISO 9283:1998 pose characteristics (7.2 AP/RP, 7.4 AD/RD)",
            "data": self.data,
            "model": self.model,
            "n_rows": self.n_rows,
            "n_poses": len(self.poses),
            "poses": [p.to_dict() for p in self.poses],
            "distance": dist,
            "before": self.summary("before"),
            "after": self.summary("after"),
            "notes": list(self.notes),
        }


def _pose_names(ds: Dataset, groups: list[np.ndarray], q: np.ndarray, tol: float) -> list[str]:
    """P1-P5 when the metadata's ISO cube program commands these joints, else ``pose k``."""
    program = ds.meta.extra.get("program") or {}
    named = {k: np.asarray(v, dtype=float) for k, v in (program.get("q") or {}).items()}
    out = []
    for k, g in enumerate(groups):
        match = [n for n, qn in named.items() if np.abs(qn - q[g[0]]).max() <= tol]
        out.append(match[0] if match else f"pose {k + 1}")
    return out


def iso9283_report(
    ds: Dataset,
    model: ErrorModel | None = None,
    *,
    data: str = "",
    model_path: str | None = None,
    tolerance_rad: float = POSE_TOLERANCE_RAD,
    min_cycles: int = 2,
) -> IsoReport:
    """AP/RP of every pose ``ds`` commands at least ``min_cycles`` times, before and (with
    ``model``) after compensation; DatasetError in one line when no pose repeats."""
    q = ds.q()
    groups = [g for g in group_repeated(q, tolerance_rad) if g.size >= min_cycles]
    if not groups:
        raise DatasetError(
            f"{data or 'dataset'}: no repeated poses among {len(ds)} rows (no commanded joint "
            f"vector occurs {min_cycles}+ times within {tolerance_rad:g} rad); ISO 9283 needs "
            f"each test pose measured over cycles (standard: 5 poses x {STANDARD_CYCLES}), e.g. "
            "`robocal sim dataset --scenario iso9283 --n 150`"
        )
    p = prepare(ds, test_fraction=0.0, spec=None if model is None else model.spec)
    desc = nominal_description(ds) if model is None else model.spec.description
    desc = desc or nominal_description(ds)
    residual = None if model is None else p.Y - model.predict(p.X).mean
    names = _pose_names(ds, groups, q, tolerance_rad)
    commanded = RobotModel(desc).fk(q[[g[0] for g in groups]])[:, :3, 3]
    poses = []
    for name, g, pc in zip(names, groups, commanded, strict=True):
        before = pose_characteristics(pc + p.Y[g, :3], p.Y[g, 3:], pc)
        after = None
        if residual is not None:
            after = pose_characteristics(pc + residual[g, :3], residual[g, 3:], pc)
        poses.append(PoseResult(name, g, q[g[0]], pc * 1e3, before, after))
    if all(pr.name.startswith("P") for pr in poses):
        poses.sort(key=lambda pr: pr.name)  # the cube program's P1-P5, not its cycle order
    notes = []
    singles = len(ds) - sum(g.size for g in groups)
    if singles:
        notes.append(f"{singles} rows command a pose fewer than {min_cycles} times: not used")
    if short := [pr for pr in poses if pr.rows.size < STANDARD_CYCLES]:
        sizes = sorted({pr.rows.size for pr in short})
        where = ", ".join(pr.name for pr in short) if len(short) <= 5 else f"{len(short)} poses"
        notes.append(
            f"fewer than the standard's {STANDARD_CYCLES} cycles at {where} "
            f"({'/'.join(map(str, sizes))} cycles)"
        )
    if model is None:
        notes.append("no --model: AP/RP before compensation only")
    distance = _distance(poses, p.Y, residual)
    if distance is None:
        notes.append(
            "distance accuracy AD/RD (clause 7.4) needs commanded distances: the ISO cube "
            "program's P2 and P4 (sim scenario iso9283); not in this dataset"
        )
    return IsoReport(data, model_path, len(ds), poses, distance, notes)


def _distance(poses: list[PoseResult], Y: np.ndarray, residual: np.ndarray | None) -> dict | None:
    """AD/RD between P2 and P4, cycle by cycle, when both are present."""
    by_name = {pr.name: pr for pr in poses}
    if not all(n in by_name for n in DISTANCE_POSES):
        return None
    a, b = (by_name[n] for n in DISTANCE_POSES)
    n = min(a.rows.size, b.rows.size)
    ra, rb = a.rows[:n], b.rows[:n]
    pa, pb = a.commanded_mm / 1e3, b.commanded_mm / 1e3

    def chars(err: np.ndarray) -> DistanceCharacteristics:
        return distance_characteristics(pa + err[ra, :3], pb + err[rb, :3], pa, pb)

    after = None if residual is None else chars(residual)
    return {"poses": DISTANCE_POSES, "before": chars(Y), "after": after}


def markdown(report: IsoReport, png_name: str | None = None) -> str:
    """The report as Markdown: one row per pose, before -> after, and the notes."""
    lines = [
        f"# ISO 9283 pose characteristics: {report.data}",
        "",
        f"{report.n_rows} rows, {len(report.poses)} repeated poses"
        + (f"; after compensation with `{report.model}`" if report.model else "")
        + ". Positions mm, orientations degrees (ISO 9283 clause 4); AP (7.2.1) is the "
        "barycentre's distance to the commanded pose, RP (7.2.2) is l̄ + 3 S_l and ±3 S.",
        "",
        "| pose | n | commanded x, y, z (mm) | AP_P mm | RP_l mm | AP_a / AP_b / AP_c deg "
        "| RP_a / RP_b / RP_c deg |",
        "|---|---|---|---|---|---|---|",
    ]

    def pair(pr: PoseResult, key: str, fmt: str) -> str:
        b = format(getattr(pr.before, key), fmt)
        return b if pr.after is None else f"{b} → {format(getattr(pr.after, key), fmt)}"

    for pr in report.poses:
        xyz = ", ".join(f"{v:.1f}" for v in pr.commanded_mm)
        ap = " / ".join(pair(pr, f"ap_{c}_deg", ".4f") for c in "abc")
        rp = " / ".join(pair(pr, f"rp_{c}_deg", ".4f") for c in "abc")
        lines.append(
            f"| {pr.name} | {pr.rows.size} | {xyz} | {pair(pr, 'ap_p_mm', '.3f')} "
            f"| {pair(pr, 'rp_l_mm', '.3f')} | {ap} | {rp} |"
        )
    if report.distance is not None:
        d, a = report.distance["before"], report.distance["after"]
        after = "" if a is None else f" → {a.ad_p_mm:.3f} mm (RD ±{a.rd_p_mm:.3f} mm)"
        lines += [
            "",
            f"Distance {' - '.join(report.distance['poses'])} (7.4, D_c {d.d_c_mm:.1f} mm, "
            f"n {d.n}): AD_P {d.ad_p_mm:.3f} mm (RD ±{d.rd_p_mm:.3f} mm){after}.",
        ]
    for which in ("before", "after"):
        s = report.summary(which)
        if s is not None:
            lines.append(
                f"\n{which.capitalize()} compensation: AP_P max {s['ap_p_max_mm']:.3f} mm "
                f"(mean {s['ap_p_mean_mm']:.3f}), RP_l max {s['rp_l_max_mm']:.3f} mm."
            )
    if png_name:
        lines += ["", f"![AP and RP per pose]({png_name})"]
    if report.notes:
        lines += ["", *(f"- {n}" for n in report.notes)]
    return "\n".join(lines) + "\n"


def save_plot(report: IsoReport, path: str | Path) -> Path:
    """A PNG of AP_P and RP_l per pose (mm), before and after compensation side by side."""
    names = [pr.name for pr in report.poses]
    x = np.arange(len(names))
    fig, ax = new_figure((8.0, 3.6))
    ax.remove()
    axes = fig.subplots(1, 2)
    for ax, key, title in zip(axes, ("ap_p_mm", "rp_l_mm"), ("AP_P", "RP_l"), strict=True):
        before = [getattr(pr.before, key) for pr in report.poses]
        ax.bar(x - 0.2, before, 0.4, label="before", color="tab:red")
        if all(pr.after is not None for pr in report.poses):
            after = [getattr(pr.after, key) for pr in report.poses]
            ax.bar(x + 0.2, after, 0.4, label="after", color="tab:blue")
            if min(before + after) > 0:
                ax.set_yscale("log")  # millimetres before, micrometres after: both readable
        if len(names) <= 12:
            ax.set_xticks(x, names)
        else:  # many poses (a dataset's own repeats): their order of first appearance
            ax.set_xlabel("pose (order of first appearance)")
        ax.set_ylabel(f"{title} (mm)")
        ax.set_title(f"ISO 9283 {title}")
        ax.legend(loc="best", fontsize="small", framealpha=0.6)
    Path(path).parent.mkdir(parents=True, exist_ok=True)
    return save_figure(fig, path)


def write_report(report: IsoReport, out: str | Path) -> tuple[Path, Path]:
    """Write ``iso9283.md`` and ``iso9283.png`` into the folder ``out``; their paths."""
    folder = Path(out)
    folder.mkdir(parents=True, exist_ok=True)
    png = save_plot(report, folder / "iso9283.png")
    md = folder / "iso9283.md"
    md.write_text(markdown(report, png.name))
    return md, png
