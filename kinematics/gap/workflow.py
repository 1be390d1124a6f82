"""The sim-vs-measured gap loop: fit a starting model, find where it disagrees with the
measurements, name the missing effect, add it, refit jointly, repeat; show the gap shrink.

Starting models: ``geometric`` (the classical calibration: identifiable DH deviations with
base and tool frame corrections; candidates are the other effects) and ``nominal`` (the
description and the dataset's believed frames; every effect is a candidate). Points are split
once (seeded) into a training part, where everything is fitted and tested, and a held-out part
where the residual is reported.

Each round scores every candidate not yet in the model (:mod:`kinematics.gap.candidates`:
projected signature, explained share, nested F-test with Holm's correction, dBIC); the
significant one (Holm p < level and dBIC < 0) with the lowest dBIC is added with its
identifiable parameters and everything is refitted jointly, the orientation weight
re-estimated from the new residual. The loop stops when no candidate is significant; whether
the held-out residual is then consistent with the noise floor is reported, not assumed.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np
from threadpoolctl import threadpool_limits

from kinematics.calibration import (
    CalibrationConfig,
    GeometricFrames,
    ResidualStats,
    apply_calibration,
    fit_under_prior,
    identify,
    residual_stats,
)
from kinematics.dataset import Dataset
from kinematics.description import RobotDescription
from kinematics.effects import EFFECTS, Effect, Restricted
from kinematics.errors import ConfigError
from kinematics.gap.candidates import CandidateScore, FitState, best, score_candidates
from kinematics.gap.formed import candidate_effects
from kinematics.gap.model_file import EffectEntry, ModelFile
from kinematics.gap.naming import NamedEffect, named_effect
from kinematics.gap.regions import (
    NoiseFloor,
    RegionStat,
    estimate_noise_floor,
    region_labels,
    region_stats,
)
from kinematics.identification.conditions import (
    Observations,
    cell_description,
    observations_from_dataset,
)
from kinematics.identification.fitting import Block, predicted_poses
from kinematics.model import RobotModel

FOLDED = ("geometric", "base_frame", "tool_frame")
STARTS = {"geometric": ("geometric", "base_frame", "tool_frame"), "nominal": ()}


@dataclass(frozen=True, kw_only=True)
class GapConfig:
    """Settings of the workflow: starting model, held-out share, seed, test level."""

    start: str = "geometric"
    test_fraction: float = 0.2
    seed: int = 0
    level: float = 0.01
    max_effects: int = 8
    max_inflation: float = 100.0
    min_value_to_std: float = 3.0
    effect_options: dict[str, dict] | None = None
    calibration: CalibrationConfig = field(default_factory=CalibrationConfig)

    def __post_init__(self) -> None:
        if self.start not in STARTS:
            raise ConfigError(f"gap.start must be one of {tuple(STARTS)}, got {self.start!r}")
        if not 0 < self.test_fraction < 1:
            raise ConfigError(f"gap.test_fraction must be in (0, 1), got {self.test_fraction}")
        if not 0 < self.level < 1:
            raise ConfigError(f"gap.level must be in (0, 1), got {self.level}")
        if self.max_effects < 0:
            raise ConfigError(f"gap.max_effects must be >= 0, got {self.max_effects}")
        if not self.max_inflation >= 1 or not self.min_value_to_std > 0:
            raise ConfigError(
                "gap.max_inflation must be >= 1 and gap.min_value_to_std > 0, got "
                f"{self.max_inflation}, {self.min_value_to_std}"
            )


@dataclass(frozen=True, kw_only=True)
class Stage:
    """The model after a step: its effects, held-out residual overall and by region."""

    label: str
    heldout: ResidualStats
    regions: list[RegionStat]
    residual_m: np.ndarray


@dataclass(frozen=True, kw_only=True)
class GapResult:
    """Everything the workflow found; :meth:`to_dict` is the ``--json`` contract."""

    robot: str
    start: str
    description: RobotDescription
    T_W_0: np.ndarray
    blocks: list[Block]
    stds: list[np.ndarray]
    noise_floor: NoiseFloor
    stages: list[Stage]
    named: list[NamedEffect]
    last_candidates: list[CandidateScore]
    not_formed: tuple[tuple[str, str], ...]
    consistent_with_floor: bool
    notes: tuple[str, ...]
    heldout_xyz_m: np.ndarray
    options: dict[str, dict]

    def model_file(self) -> ModelFile:
        """The updated model: folded description and ``T_W_0`` plus the other effects."""
        entries = []
        identified = {e.effect: e.identified for e in self.named}
        for (effect, p), std in zip(self.blocks, self.stds, strict=True):
            if isinstance(effect, GeometricFrames) or effect.name in FOLDED:
                continue
            entries.append(
                EffectEntry(
                    name=effect.name,
                    identified=identified.get(effect.name, True),
                    options=effect.options(),
                    parameters=_named_values(
                        effect.effect.parameter_names(self.description), effect.full(p)
                    ),
                    std=_named_values(effect.parameter_names(self.description), std),
                )
            )
        return ModelFile(description=self.description, T_W_0=self.T_W_0, effects=tuple(entries))

    def to_dict(self) -> dict:
        before, after = self.stages[0], self.stages[-1]
        return {
            "robot": self.robot,
            "start": self.start,
            "disagreement": [r.to_dict() for r in before.regions if r.significant],
            "named_effects": [e.to_dict() for e in self.named if e.identified],
            "unnamed_corrections": [e.to_dict() for e in self.named if not e.identified],
            "candidates_last_round": [c.to_dict() for c in self.last_candidates],
            "candidates_not_formed": [{"effect": n, "why": w} for n, w in self.not_formed],
            "before": before.heldout.to_dict(),
            "after": after.heldout.to_dict(),
            "stages": [
                {
                    "label": s.label,
                    "heldout": s.heldout.to_dict(),
                    "regions": [r.to_dict() for r in s.regions],
                }
                for s in self.stages
            ],
            "noise_floor_mm": self.noise_floor.mean_m * 1e3,
            "noise_floor_source": self.noise_floor.source,
            "consistent_with_noise_floor": self.consistent_with_floor,
            "notes": list(self.notes),
        }


def _named_values(names, values) -> dict[str, float]:
    return dict(zip(names, map(float, values), strict=True))


def split(n: int, test_fraction: float, seed: int) -> tuple[np.ndarray, np.ndarray]:
    """Seeded train / held-out positions of ``n`` points."""
    perm = np.random.default_rng(seed).permutation(n)
    n_test = max(1, int(round(test_fraction * n)))
    return np.sort(perm[n_test:]), np.sort(perm[:n_test])


def _start_blocks(
    start: str, model: RobotModel, obs: Observations, config: GapConfig
) -> list[Block]:
    if start == "nominal":
        return []
    desc = model.description
    ident = identify(model, obs, config.calibration)
    return [(GeometricFrames(desc, ident.kept_index), np.zeros(len(ident.kept)))]


def run_gap(
    desc: RobotDescription,
    ds: Dataset,
    config: GapConfig | None = None,
    progress: Callable[[str], None] | None = None,
) -> GapResult:
    """Run the workflow on ``ds`` for robot ``desc`` (see the module docstring).

    Linear algebra runs single-threaded: its matrices are thin, and threaded BLAS on a busy
    machine is many times slower.
    """
    with threadpool_limits(limits=1, user_api="blas"):
        return _run_gap(desc, ds, config, progress)


def _run_gap(desc, ds, config, progress) -> GapResult:
    config = config or GapConfig()
    say = progress or (lambda _msg: None)
    desc = cell_description(desc, ds)
    model = RobotModel(desc)
    obs = observations_from_dataset(ds, desc)
    deflection = ds.deflection()
    train, test = split(len(ds), config.test_fraction, config.seed)
    obs_tr, obs_te = obs.subset(train), obs.subset(test)
    notes = list(obs.notes)
    options = _effect_options(ds, config)
    blocks = _start_blocks(config.start, model, obs_tr, config)
    say(f"fitting the {config.start} start")
    fit = fit_under_prior(model, obs_tr, blocks, config.calibration)
    blocks = fit.blocks([e for e, _ in blocks])
    xyz = model.fk(obs_te.cond.q)[:, :3, 3]
    labels = region_labels(obs_te, xyz, None if deflection is None else deflection[test])
    floor = _noise_floor(ds, model, obs_tr, blocks)
    stages = [_stage(config.start, model, obs_te, blocks, labels, floor, config.level)]
    included = set(STARTS[config.start])
    named: list[NamedEffect] = []
    scores: list[CandidateScore] = []
    not_formed: list[tuple[str, str]] = []
    stop = f"stopped after max_effects = {config.max_effects} effects"
    while len(named) < config.max_effects:
        candidates = [n for n in EFFECTS if n not in included]
        if not candidates:
            stop = "every effect of the vocabulary is in the model"
            break
        say(f"scoring {len(candidates)} candidates")
        r = _weighted(fit.residual, fit.rotation_weight_m)
        state = FitState(blocks, fit.jac, r, fit.rotation_weight_m)
        formed, not_formed = candidate_effects(
            candidates, options, model, obs_tr, state, config.level
        )
        by_name = {e.name if isinstance(e, Effect) else e.effect: e for e in formed}
        scores = score_candidates(formed, model, obs_tr, state, config.level)
        top = best(scores)
        if top is None:
            stop = "no candidate of the vocabulary explains the residual significantly"
            break
        say(f"adding {top.effect}")
        new = Restricted(by_name[top.effect], desc, top.kept_index)
        effects = [*(e for e, _ in blocks), new]
        start = [*(p for _, p in blocks), np.zeros(len(top.kept_index))]
        grown = list(zip(effects, start, strict=True))
        fit = fit_under_prior(model, obs_tr, grown, config.calibration)
        blocks = fit.blocks(effects)
        included.add(top.effect)
        named.append(named_effect(top, fit, scores, config.max_inflation, config.min_value_to_std))
        label = f"+ {top.effect}" if named[-1].identified else f"+ unnamed ({top.effect} shape)"
        stages.append(_stage(label, model, obs_te, blocks, labels, floor, config.level))
    final = stages[-1].regions[0]
    consistent = not final.significant
    if not consistent:
        notes.append(f"the held-out residual stays above the noise floor; {stop}")
    out_desc, T_W_0 = fold(desc, obs.T_W_0, blocks)
    return GapResult(
        robot=desc.name,
        start=config.start,
        description=out_desc,
        T_W_0=T_W_0,
        blocks=blocks,
        stds=fit.std,
        noise_floor=floor,
        stages=stages,
        named=named,
        last_candidates=scores,
        not_formed=tuple(not_formed),
        consistent_with_floor=consistent,
        notes=tuple(notes),
        heldout_xyz_m=xyz,
        options=options,
    )


def _effect_options(ds: Dataset, config: GapConfig) -> dict[str, dict]:
    """Candidate constructor options: the config's, else the dataset meta's ``effect_options``
    (structural facts of the cell such as a J2 balancer or the gear orders), else defaults."""
    if config.effect_options is not None:
        return config.effect_options
    extra = ds.meta.extra if isinstance(ds.meta.extra, dict) else {}
    options = extra.get("effect_options", {})
    return options if isinstance(options, dict) else {}


def _weighted(E: np.ndarray, w: float) -> np.ndarray:
    return np.concatenate([E[:, :3], w * E[:, 3:]], axis=1).ravel()


def _noise_floor(ds: Dataset, model, obs_tr: Observations, blocks) -> NoiseFloor:
    if ds.meta.noise_floor_m is not None:
        return NoiseFloor(mean_m=float(ds.meta.noise_floor_m), source="dataset meta noise_floor_m")
    E = obs_tr.T_measured[:, :3, 3] - predicted_poses(model, obs_tr, blocks)[:, :3, 3]
    return estimate_noise_floor(np.asarray(obs_tr.cond.q), E)


def _stage(label, model, obs_te, blocks, labels, floor, level) -> Stage:
    T = predicted_poses(model, obs_te, blocks)
    E = obs_te.T_measured[:, :3, 3] - T[:, :3, 3]
    return Stage(
        label=label,
        heldout=residual_stats(obs_te.T_measured, T),
        regions=region_stats(E, labels, floor, level),
        residual_m=E,
    )


def fold(
    desc: RobotDescription, T_W_0: np.ndarray, blocks: list[Block]
) -> tuple[RobotDescription, np.ndarray]:
    """Fold geometric and frame blocks into the description and ``T_W_0``; others stay."""
    n = desc.n_joints
    values = np.zeros(5 * n + 12)
    for effect, p in blocks:
        if isinstance(effect, GeometricFrames):
            values += effect.full(p)
        elif isinstance(effect, Restricted) and effect.name == "geometric":
            values[: 5 * n] += effect.full(p)
        elif isinstance(effect, Restricted) and effect.name in FOLDED:
            at = 5 * n if effect.name == "base_frame" else 5 * n + 6
            values[at : at + 6] += effect.full(p)
    return apply_calibration(desc, T_W_0, values)


__all__ = ["GapConfig", "GapResult", "NamedEffect", "Stage", "fold", "run_gap", "split"]
