"""Naming an added effect only when the data identify its parameters.

After the joint refit with a new effect, two numbers decide: the largest std inflation of its
parameters (``sqrt`` of the variance inflation factor, from the unit-norm refit Jacobian: how
far the rest of the model blurs them; 1 = orthogonal) and the largest ``|value| / std`` among
them. Within the limits the effect is named; otherwise the correction stays in the model as an
unnamed term and the report says that a correction of this shape helps but is not
identifiable as that effect from these poses.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from kinematics.gap.candidates import CandidateScore
from kinematics.identification.fitting import FitResult


@dataclass(frozen=True, kw_only=True)
class NamedEffect:
    """An effect added to the model: parameter values and uncertainties (SI), the evidence,
    the condition number of the joint refit (unit-norm columns) and the largest std inflation
    of its parameters there (``sqrt`` of the variance inflation factor: how much the rest of
    the model blurs them). ``identified`` when the inflation stays within the config's limit
    and some parameter exceeds its std enough; otherwise the correction helps but is not
    named (:attr:`message`)."""

    effect: str
    parameters: dict[str, float]
    std: dict[str, float]
    evidence: CandidateScore
    candidates: list[CandidateScore]
    fit_condition_number: float
    inflation: float = 1.0
    value_to_std: float = float("inf")
    identified: bool = True

    @property
    def message(self) -> str:
        """One line on what was added."""
        if self.identified:
            return f"{self.effect} identified"
        return (
            f"a correction of this shape helps, but it is not identifiable as `{self.effect}` "
            f"from these poses (std inflation {self.inflation:.3g}, largest value/std "
            f"{self.value_to_std:.3g}, joint refit condition number "
            f"{self.fit_condition_number:.3g})"
        )

    def to_dict(self) -> dict:
        return {
            "effect": self.effect,
            "identified": self.identified,
            "message": self.message,
            "parameters": self.parameters,
            "std": self.std,
            "evidence": self.evidence.to_dict(),
            "fit_condition_number": self.fit_condition_number,
            "inflation": self.inflation,
            "value_to_std": self.value_to_std,
        }


def named_effect(
    top: CandidateScore,
    fit: FitResult,
    scores: list[CandidateScore],
    max_inflation: float,
    min_value_to_std: float,
) -> NamedEffect:
    """The added effect with its identifiability: std inflation of its parameters in the joint
    refit (unit-norm columns) and the largest |value| / std among them."""
    names = top.kept
    J = fit.jac / np.maximum(np.linalg.norm(fit.jac, axis=0), 1e-300)
    sv = np.linalg.svd(J, compute_uv=False)
    k = len(names)
    inflation = float(np.sqrt(np.max(np.diag(np.linalg.pinv(J.T @ J))[-k:])))
    value, std = np.abs(fit.params[-1]), fit.std[-1]
    ratio = float(np.max(np.divide(value, std, out=np.full(k, np.inf), where=std > 0)))
    return NamedEffect(
        effect=top.effect,
        parameters=dict(zip(names, map(float, fit.params[-1]), strict=True)),
        std=dict(zip(names, map(float, fit.std[-1]), strict=True)),
        evidence=top,
        candidates=scores,
        fit_condition_number=float(sv[0] / sv[-1]),
        inflation=inflation,
        value_to_std=ratio,
        identified=inflation <= max_inflation and ratio >= min_value_to_std,
    )


__all__ = ["NamedEffect", "named_effect"]
