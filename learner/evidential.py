"""Deep evidential regression (Amini et al. 2020): the NIG loss and the Student-t predictive.

A network outputs a Normal-Inverse-Gamma ``(gamma, nu, alpha, beta)`` per label component
(``nu, beta > 0``, ``alpha > 1``). Its marginal predictive is a Student-t with ``2 alpha``
degrees of freedom, location ``gamma`` and scale² ``beta (1 + nu) / (nu alpha)``; the loss is
that distribution's negative log density plus an evidence regulariser. In training, each
point's negative log density can be weighed by its predicted variance to a power ``p``, held
constant in the gradient (β-NLL, Seitzer et al. 2022): at ``p = 0`` a network may leave points
it fits badly to a large variance and stop fitting them; at ``p = 1`` its mean learns as under
the squared error.

>>> import numpy as np
>>> ev = Evidential(gamma=np.zeros((1, 6)), nu=np.ones((1, 6)), alpha=np.full((1, 6), 2.0),
...                 beta=np.ones((1, 6)))
>>> float(ev.aleatoric()[0, 0]), float(ev.epistemic()[0, 0])
(1.0, 1.0)
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import TypeVar

import numpy as np
import torch
from scipy import stats
from scipy.special import gammaln

from kinematics.errors import ConfigError

_LOG_PI = math.log(math.pi)
#: NIG parameters as arrays, tensors or numbers alike.
Values = TypeVar("Values", np.ndarray, torch.Tensor, float)


def served_mean(gamma: Values, nu: Values, alpha: Values, beta: Values) -> Values:
    """The mean a model serves, in scaled label units: the network's ``gamma`` weighed against
    the residual's prior N(0, 1) by its epistemic variance ``beta / (nu (alpha - 1))``, so that
    where the network does not know, the prediction falls back to the base. Early stopping
    scores this (:mod:`learner.training`).

    >>> served_mean(2.0, nu=1.0, alpha=2.0, beta=1.0)  # epistemic variance 1: halfway
    1.0
    """
    return gamma / (1.0 + beta / (nu * (alpha - 1.0)))


def nig_nll(
    y: torch.Tensor, gamma: torch.Tensor, nu: torch.Tensor, alpha: torch.Tensor, beta: torch.Tensor
) -> torch.Tensor:
    """Elementwise ``L_NLL`` of DESIGN.md: ``-log St(y; gamma, 2 alpha, beta(1+nu)/(nu alpha))``."""
    omega = 2.0 * beta * (1.0 + nu)
    return (
        0.5 * (_LOG_PI - torch.log(nu))
        - alpha * torch.log(omega)
        + (alpha + 0.5) * torch.log(nu * (y - gamma) ** 2 + omega)
        + torch.lgamma(alpha)
        - torch.lgamma(alpha + 0.5)
    )


def nig_regularizer(
    y: torch.Tensor, gamma: torch.Tensor, nu: torch.Tensor, alpha: torch.Tensor
) -> torch.Tensor:
    """Elementwise evidence regulariser ``|y - gamma| (2 nu + alpha)``: penalises evidence on
    wrong predictions."""
    return torch.abs(y - gamma) * (2.0 * nu + alpha)


def evidential_elements(
    y: torch.Tensor,
    gamma: torch.Tensor,
    nu: torch.Tensor,
    alpha: torch.Tensor,
    beta: torch.Tensor,
    lam: float,
    power: float = 0.0,
) -> torch.Tensor:
    """Elementwise ``w L_NLL + lam L_R``, ``w`` the predictive variance
    ``beta (1 + nu) / (nu (alpha - 1))`` to the ``power``, held constant in the gradient; the
    training loss is their mean."""
    nll = nig_nll(y, gamma, nu, alpha, beta)
    if power:
        nll = nll * (beta * (1.0 + nu) / (nu * (alpha - 1.0))).detach() ** power
    return nll + lam * nig_regularizer(y, gamma, nu, alpha)


def combine_members(
    gamma: torch.Tensor, nu: torch.Tensor, alpha: torch.Tensor, beta: torch.Tensor, members: int
) -> tuple[torch.Tensor, ...]:
    """One NIG per component from ``members`` independently trained NIGs (heads ``(N, M * C)``,
    member-major): the mean of the members' ``gamma`` and ``alpha``, their mean aleatoric
    variance, and as epistemic variance their mean epistemic variance plus the variance of
    their ``gamma`` — members that disagree do not know. ``beta`` and ``nu`` follow from
    ``aleatoric = beta / (alpha - 1)`` and ``epistemic = beta / (nu (alpha - 1))``.
    """
    if members == 1:
        return gamma, nu, alpha, beta
    shape = (gamma.shape[0], members, gamma.shape[1] // members)  # explicit: also for 0 rows
    g, n, a, b = (t.reshape(shape) for t in (gamma, nu, alpha, beta))
    alea = (b / (a - 1.0)).mean(dim=1)
    gamma_c = g.mean(dim=1)
    # The spread written out: Tensor.var over a middle axis is ~6 × slower for 1,000 rows.
    spread = (g - gamma_c.unsqueeze(1)).square().mean(dim=1)
    epi = (b / (n * (a - 1.0))).mean(dim=1) + spread
    alpha_c = a.mean(dim=1)
    return gamma_c, alea / epi, alpha_c, alea * (alpha_c - 1.0)


@dataclass(frozen=True, kw_only=True)
class Evidential:
    """NIG parameters ``(N, 6)`` in label units (m for position, rad for orientation)."""

    gamma: np.ndarray
    nu: np.ndarray
    alpha: np.ndarray
    beta: np.ndarray

    @property
    def mean(self) -> np.ndarray:
        """The prediction ``gamma`` (label units)."""
        return self.gamma

    def aleatoric(self) -> np.ndarray:
        """Expected data variance ``E[sigma²] = beta / (alpha - 1)`` (label units²)."""
        return self.beta / (self.alpha - 1.0)

    def epistemic(self) -> np.ndarray:
        """Variance of the mean ``Var[mu] = beta / (nu (alpha - 1))`` (label units²)."""
        return self.beta / (self.nu * (self.alpha - 1.0))

    def scale(self) -> np.ndarray:
        """Student-t scale ``sqrt(beta (1 + nu) / (nu alpha))`` (label units)."""
        return np.sqrt(self.beta * (1.0 + self.nu) / (self.nu * self.alpha))

    def interval(self, level: float) -> tuple[np.ndarray, np.ndarray]:
        """Central ``level`` interval ``(lo, hi)`` of the Student-t predictive (label units)."""
        if not 0.0 < level < 1.0:
            raise ConfigError(f"interval level must be in (0, 1), got {level}")
        half = stats.t.ppf(0.5 + level / 2.0, df=2.0 * self.alpha) * self.scale()
        return self.gamma - half, self.gamma + half

    def nll(self, y: np.ndarray) -> np.ndarray:
        """Elementwise negative log predictive density of ``y`` (same units as the labels)."""
        nu, alpha, beta = self.nu, self.alpha, self.beta
        omega = 2.0 * beta * (1.0 + nu)
        return (
            0.5 * (_LOG_PI - np.log(nu))
            - alpha * np.log(omega)
            + (alpha + 0.5) * np.log(nu * (y - self.gamma) ** 2 + omega)
            + gammaln(alpha)
            - gammaln(alpha + 0.5)
        )

    def __len__(self) -> int:
        return int(self.gamma.shape[0])
