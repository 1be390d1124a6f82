"""Forming the candidates for a robot and a dataset: what each needs, and thermal from the data.

An effect of the vocabulary can be a candidate only when the robot and the dataset give it the
signals it needs (:meth:`kinematics.effects.Effect.needs`: gravity torques need link masses, a
payload or a tool force; thermal growth needs temperature channels; drift needs time stamps
that vary); otherwise it is listed as not formed, with the reason.

Thermal expansion is formed in one of three ways: the constructor options a dataset's metadata
or the config give; the description's ``[sensors.temperature_links]`` map (each mapped link's
lengths grow with the mean of its channels; a map naming columns the dataset lacks is bad input);
or, without a map, from the data: every (link, channel) pair is a possible term, and terms are
added one at a time, largest explained residual first, while the term's growth is positive, its
F-test passes at ``level`` Bonferroni-corrected over the pairs tried and the BIC falls. The
chosen terms become a :class:`~kinematics.effects.ThermalExpansion` candidate, scored like every
other candidate. Channels that cannot be told apart (correlation above ``1 - 1e-6``) make the
pairs ambiguous and are bad input.
"""

from __future__ import annotations

import numpy as np
from scipy.stats import f as f_dist

from kinematics.dataset import temperature_column
from kinematics.description import RobotDescription
from kinematics.effects import Effect, ThermalExpansion
from kinematics.errors import DatasetError, RobocalError
from kinematics.gap.candidates import CandidateScore, FitState, make_effect, untestable
from kinematics.identification.conditions import Observations
from kinematics.identification.fitting import jacobian
from kinematics.model import RobotModel

#: Two standardised channels closer than this in correlation cannot be told apart.
_SAME_CHANNEL_CORR = 1 - 1e-6


def check_temperatures(obs: Observations) -> None:
    """Raise :class:`DatasetError` when two varying temperature channels cannot be told apart."""
    T, names = obs.cond.temperatures, obs.cond.temperature_names
    if T is None or T.shape[1] < 2:
        return
    std = T.std(axis=0)
    live = np.flatnonzero(std > 1e-9)
    Z = (T[:, live] - T[:, live].mean(axis=0)) / std[live]
    corr = np.abs(Z.T @ Z) / len(Z)
    np.fill_diagonal(corr, 0)
    if corr.size and corr.max() > _SAME_CHANNEL_CORR:
        i, j = np.unravel_index(np.argmax(corr), corr.shape)
        raise DatasetError(
            f"temperature channels {temperature_column(names[live[i]])} and "
            f"{temperature_column(names[live[j]])} cannot be "
            f"told apart (correlation {corr[i, j]:.7f}); drop one, or map them to links in the "
            "description's [sensors.temperature_links]"
        )


def mapped_thermal(desc: RobotDescription, obs: Observations, t_ref_c: float = 20.0):
    """The thermal candidate of the description's ``[sensors]`` map, or None without a map."""
    if not desc.temperature_links:
        return None
    names = set(obs.cond.temperature_names)
    missing = sorted({c for c, _ in desc.temperature_links} - names)
    if missing and names:
        raise DatasetError(
            f"the description's [sensors] map names temperature channel(s) "
            f"{', '.join(map(temperature_column, missing))} that the dataset lacks "
            f"(it has {', '.join(map(temperature_column, sorted(names)))})"
        )
    terms = tuple((i + 1, chs) for i, chs in enumerate(desc.link_channels()) if chs)
    return ThermalExpansion(terms=terms, t_ref_c=t_ref_c)


def candidate_effects(
    names: list[str],
    options: dict[str, dict],
    model: RobotModel,
    obs: Observations,
    fit_state: FitState,
    level: float,
) -> tuple[list[Effect | CandidateScore], list[tuple[str, str]]]:
    """The candidates to score (an effect, or a score for one that was formed empty) and the
    ones not formed with the reason. ``fit_state``: blocks, Jacobian, weighted residual, ``w``."""
    out: list[Effect | CandidateScore] = []
    not_formed: list[tuple[str, str]] = []
    for name in names:
        effect = make_effect(name, options.get(name))
        if name == "thermal_expansion" and name not in options:
            effect = mapped_thermal(model.description, obs) or effect
        need = effect.needs(model, obs.cond)
        if need is not None:
            not_formed.append((name, need))
            continue
        if isinstance(effect, ThermalExpansion) and not effect.terms and name not in options:
            effect = thermal_from_data(model, obs, fit_state, level)
        out.append(effect)
    return out, not_formed


def thermal_from_data(
    model: RobotModel,
    obs: Observations,
    fit_state: FitState,
    level: float,
    absorb_rtol: float = 1e-2,
) -> ThermalExpansion | CandidateScore:
    """The data-formed thermal candidate (module docstring), or an untestable score."""
    check_temperatures(obs)
    blocks, current_jac, residual, w = fit_state
    desc = model.description
    pairs = tuple(
        (i + 1, (c,))
        for i, j in enumerate(desc.joints)
        if j.a_m != 0 or j.d_m != 0
        for c in obs.cond.temperature_names
    )
    full = ThermalExpansion(terms=pairs)
    n_all = len(pairs)
    try:
        Jc = jacobian(model, obs, [*blocks, (full, np.zeros(n_all))], w, len(blocks))
    except RobocalError as exc:
        return untestable(full.name, n_all, f"not testable with this dataset: {exc}")
    if current_jac.shape[1]:
        Q, _ = np.linalg.qr(current_jac)
        Jc = Jc - Q @ (Q.T @ Jc)
    chosen = select_terms(Jc, residual, current_jac.shape[1], level, absorb_rtol)
    if not chosen:
        return untestable(
            full.name, n_all, "formed from the data: no (link, channel) term passes the test"
        )
    return ThermalExpansion(terms=tuple(pairs[i] for i in chosen))


def select_terms(
    Jp: np.ndarray, r: np.ndarray, p0: int, level: float, absorb_rtol: float = 1e-2
) -> list[int]:
    """Forward selection of columns of the projected signature ``Jp`` (m, P) explaining the
    residual ``r`` with a positive parameter (``-(v . r) / |v|^2 > 0``), each passing an F-test
    at ``level / P`` and lowering the BIC; a final joint fit drops terms turned negative."""
    m = r.size
    norms = np.linalg.norm(Jp, axis=0)
    tried = max(int(np.sum(norms > 0)), 1)
    basis = np.zeros((m, 0))
    resid, rss = r.astype(float), float(r @ r)
    chosen: list[int] = []
    while len(chosen) < Jp.shape[1]:
        V = Jp - basis @ (basis.T @ Jp)
        vn = np.linalg.norm(V, axis=0)
        ok = (vn > absorb_rtol * norms) & (norms > 0)
        ok[chosen] = False
        proj = V.T @ resid
        gain = np.where(ok & (proj < 0), proj**2 / np.where(ok, vn, 1.0) ** 2, 0.0)
        j = int(np.argmax(gain))
        if gain[j] <= 0:
            break
        dof = m - p0 - len(chosen) - 1
        f_stat = gain[j] / max(rss - gain[j], 1e-300) * dof
        if (
            f_dist.sf(f_stat, 1, dof) * tried >= level
            or m * np.log1p(-gain[j] / rss) + np.log(m) >= 0
        ):
            break
        u = V[:, j] / vn[j]
        basis = np.column_stack([basis, u])
        resid = resid - u * (u @ resid)
        rss -= float(gain[j])
        chosen.append(j)
    while chosen:
        coef, *_ = np.linalg.lstsq(Jp[:, chosen], r, rcond=None)
        if np.all(coef < 0):
            break
        chosen = [c for c, k in zip(chosen, coef, strict=True) if k < 0]
    return sorted(chosen)


__all__ = [
    "candidate_effects",
    "check_temperatures",
    "mapped_thermal",
    "select_terms",
    "thermal_from_data",
]
