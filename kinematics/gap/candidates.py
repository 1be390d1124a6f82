"""Name the missing effect: score each candidate by what it explains beyond the current model.

A candidate's signature is the Jacobian of the residual w.r.t. its parameters at zero
(finite differences through ``perturbed_poses``). What the current model already explains is
projected out (the orthogonal complement of the current Jacobian's column space); parameters
whose projected column keeps less than ``absorb_rtol`` (1%) of its norm cannot be told apart
from the current model, and the rest are thinned to an independent set by pivoted QR
(``rank_rtol`` 1e-3 on unit-norm columns, so the kept set's condition number stays below about
1e3; looser limits let a poorly excited effect fit huge, cancelling parameters). The
projected signature is scored by the share of the residual it explains, a nested F-test and
the change of BIC; p-values are Holm-corrected over the candidates.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import NamedTuple

import numpy as np
from scipy.stats import f as f_dist

from kinematics.calibration import identifiable
from kinematics.effects import EFFECTS, Effect
from kinematics.errors import ConfigError, RobocalError
from kinematics.identification.conditions import Observations
from kinematics.identification.fitting import Block, jacobian
from kinematics.model import RobotModel


class FitState(NamedTuple):
    """The current fit a candidate is scored against: its blocks, Jacobian (m, p0), weighted
    residual (m,) and the rotation weight ``w`` (m/rad) that weighted it."""

    blocks: list[Block]
    jac: np.ndarray
    residual: np.ndarray
    w: float


@dataclass(frozen=True, kw_only=True)
class CandidateScore:
    """The evidence for one candidate effect against the current model."""

    effect: str
    n_parameters: int
    kept: tuple[str, ...]
    absorbed: tuple[str, ...]
    explained_share: float
    f_stat: float
    p_value: float
    p_holm: float
    delta_bic: float
    significant: bool
    note: str
    condition_number: float = float("nan")
    kept_index: tuple[int, ...] = ()

    def to_dict(self) -> dict:
        out = {k: getattr(self, k) for k in self.__dataclass_fields__ if k != "kept_index"}
        out["kept"], out["absorbed"] = list(self.kept), list(self.absorbed)
        return out


def untestable(name: str, n_params: int, note: str, absorbed=()) -> CandidateScore:
    return CandidateScore(
        effect=name,
        n_parameters=n_params,
        kept=(),
        absorbed=tuple(absorbed),
        explained_share=0.0,
        f_stat=0.0,
        p_value=1.0,
        p_holm=1.0,
        delta_bic=0.0,
        significant=False,
        note=note,
    )


def make_effect(name: str, options: dict | None = None) -> Effect:
    """The effect ``name`` built with constructor ``options`` (lists become tuples; the value
    ``"default"`` keeps the default), e.g. a dataset meta's ``effect_options``.

    >>> make_effect("gear_periodic", {"orders": [1, 2]}).orders
    (1, 2)
    """
    if name not in EFFECTS:
        raise ConfigError(f"unknown effect {name!r}; known: {', '.join(EFFECTS)}")
    kwargs = {
        k: tuple(v) if isinstance(v, list) else v
        for k, v in (options or {}).items()
        if v != "default"
    }
    try:
        return EFFECTS[name](**kwargs)
    except TypeError as exc:
        raise ConfigError(f"effect {name!r}: bad options {options}: {exc}") from None


def score_candidate(
    effect: Effect,
    model: RobotModel,
    obs: Observations,
    state: FitState,
    absorb_rtol: float = 1e-2,
    rank_rtol: float = 1e-3,
) -> CandidateScore:
    """Score ``effect`` against the current fit ``state``; the Holm correction is applied by
    :func:`score_candidates`."""
    blocks, current_jac, residual, w = state
    desc = model.description
    name = effect.name
    names = effect.parameter_names(desc)
    try:
        Jc = jacobian(model, obs, [*blocks, (effect, effect.zero_parameters(desc))], w, len(blocks))
    except RobocalError as exc:
        return untestable(name, len(names), f"not testable with this dataset: {exc}")
    norms = np.linalg.norm(Jc, axis=0)
    if current_jac.shape[1]:
        Q, _ = np.linalg.qr(current_jac)
        Jp = Jc - Q @ (Q.T @ Jc)
    else:
        Jp = Jc
    kept_norm = np.divide(
        np.linalg.norm(Jp, axis=0), norms, out=np.zeros_like(norms), where=norms > 0
    )
    live = np.flatnonzero(kept_norm >= absorb_rtol)
    absorbed = tuple(names[i] for i in np.flatnonzero((kept_norm < absorb_rtol) & (norms > 0)))
    if not np.any(norms > 0):
        return untestable(name, len(names), "not excited by these poses and conditions")
    if live.size == 0:
        return untestable(
            name,
            len(names),
            "cannot be told apart from the current model with these poses",
            absorbed,
        )
    sub = identifiable(Jp[:, live], tuple(names[i] for i in live), rank_rtol)
    idx = tuple(int(live[i]) for i in sub.kept_index)
    A = Jp[:, list(idx)]
    coef, *_ = np.linalg.lstsq(A, residual, rcond=None)
    explained = float(np.sum((A @ coef) ** 2))
    rss0 = float(residual @ residual)
    rss1 = max(rss0 - explained, 1e-300)
    m, k = residual.size, len(idx)
    dof = m - current_jac.shape[1] - k
    f_stat = (explained / k) / (rss1 / dof)
    return CandidateScore(
        effect=name,
        n_parameters=len(names),
        kept=tuple(names[i] for i in idx),
        absorbed=absorbed,
        explained_share=explained / rss0 if rss0 > 0 else 0.0,
        f_stat=float(f_stat),
        p_value=float(f_dist.sf(f_stat, k, dof)),
        p_holm=1.0,
        delta_bic=float(m * np.log(rss1 / rss0) + k * np.log(m)),
        significant=False,
        note="",
        condition_number=sub.condition_number,
        kept_index=idx,
    )


def holm(p_values: list[float]) -> list[float]:
    """Holm-adjusted p-values (step-down, monotone).

    >>> [round(p, 3) for p in holm([0.01, 0.04, 0.03])]
    [0.03, 0.06, 0.06]
    """
    order = np.argsort(p_values)
    m = len(p_values)
    adjusted, running = [0.0] * m, 0.0
    for rank, i in enumerate(order):
        running = max(running, min(1.0, (m - rank) * p_values[i]))
        adjusted[i] = running
    return adjusted


def score_candidates(
    effects: list[Effect | CandidateScore],
    model: RobotModel,
    obs: Observations,
    state: FitState,
    level: float = 0.01,
) -> list[CandidateScore]:
    """Every candidate scored (one given as a score is taken as it is), Holm-corrected at
    ``level``; significant ones also need a negative change of BIC."""
    scores = [
        e if isinstance(e, CandidateScore) else score_candidate(e, model, obs, state)
        for e in effects
    ]
    adjusted = holm([s.p_value for s in scores]) if scores else []
    out = []
    for s, p in zip(scores, adjusted, strict=True):
        significant = bool(s.kept) and p < level and s.delta_bic < 0
        out.append(CandidateScore(**{**s.__dict__, "p_holm": float(p), "significant": significant}))
    return out


def best(scores: list[CandidateScore]) -> CandidateScore | None:
    """The significant candidate with the lowest change of BIC, or None."""
    sig = [s for s in scores if s.significant]
    return min(sig, key=lambda s: s.delta_bic) if sig else None
