"""Sparse GP benchmark (Titsias SGPR via gpytorch): one GP per label component.

The comparison model of the reference study. gpytorch is an optional (``bench``) dependency,
imported only here; inputs use the same fixed input encoding as :class:`ErrorModel`.
"""

from __future__ import annotations

import numpy as np
import torch

from kinematics.errors import ConfigError
from learner.encoding import input_encoder
from learner.features import FeatureSpec


def fit_predict_sgpr(
    spec: FeatureSpec,
    X: np.ndarray,
    Y: np.ndarray,
    X_test: np.ndarray,
    *,
    n_inducing: int = 200,
    iterations: int = 150,
    seed: int = 0,
    encoding: str = "kinematic",
) -> np.ndarray:
    """Fit six SGPRs (ARD RBF, ``n_inducing`` points from the data) and predict means (N, 6)."""
    try:
        import gpytorch
    except ImportError:
        raise ConfigError("the SGPR benchmark needs gpytorch (pip install gpytorch)") from None

    class _SGPR(gpytorch.models.ExactGP):
        def __init__(self, x, y, likelihood, inducing):
            super().__init__(x, y, likelihood)
            self.mean_module = gpytorch.means.ConstantMean()
            base = gpytorch.kernels.ScaleKernel(gpytorch.kernels.RBFKernel(ard_num_dims=x.shape[1]))
            self.covar_module = gpytorch.kernels.InducingPointKernel(
                base, inducing_points=inducing, likelihood=likelihood
            )

        def forward(self, x):
            return gpytorch.distributions.MultivariateNormal(
                self.mean_module(x), self.covar_module(x)
            )

    gen = torch.Generator().manual_seed(seed)
    encode = input_encoder(spec, encoding)
    x = torch.as_tensor(encode(X), dtype=torch.float64)
    xt = torch.as_tensor(encode(X_test), dtype=torch.float64)
    mean, std = Y.mean(axis=0), Y.std(axis=0) + 1e-15
    out = np.empty((len(X_test), Y.shape[1]))
    for c in range(Y.shape[1]):
        y = torch.as_tensor((Y[:, c] - mean[c]) / std[c], dtype=torch.float64)
        idx = torch.randperm(len(x), generator=gen)[: min(n_inducing, len(x))]
        likelihood = gpytorch.likelihoods.GaussianLikelihood().double()
        model = _SGPR(x, y, likelihood, x[idx].clone()).double()
        model.train()
        likelihood.train()
        opt = torch.optim.Adam(model.parameters(), lr=0.05)
        mll = gpytorch.mlls.ExactMarginalLogLikelihood(likelihood, model)
        for _ in range(iterations):
            opt.zero_grad()
            loss = -mll(model(x), y)
            loss.backward()
            opt.step()
        model.eval()
        likelihood.eval()
        with torch.no_grad(), gpytorch.settings.fast_pred_var():
            out[:, c] = mean[c] + std[c] * model(xt).mean.numpy()
    return out
