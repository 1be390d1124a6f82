import numpy as np
import pytest
import torch
from scipy import stats

from kinematics.errors import ConfigError
from learner.config import TrainConfig
from learner.evidential import Evidential, evidential_elements, nig_nll, nig_regularizer


def _params(rng, n=50):
    return (
        rng.normal(size=n),
        rng.normal(size=n),
        rng.uniform(0.05, 5.0, n),
        rng.uniform(1.05, 8.0, n),
        rng.uniform(0.01, 3.0, n),
    )


def test_nll_is_minus_log_student_t_density():
    y, gamma, nu, alpha, beta = _params(np.random.default_rng(0))
    t = [torch.as_tensor(a, dtype=torch.float64) for a in (y, gamma, nu, alpha, beta)]
    got = nig_nll(*t).numpy()
    scale = np.sqrt(beta * (1 + nu) / (nu * alpha))
    want = -stats.t.logpdf(y, df=2 * alpha, loc=gamma, scale=scale)
    np.testing.assert_allclose(got, want, rtol=1e-10, atol=1e-10)


def test_numpy_nll_matches_torch_nll():
    y, gamma, nu, alpha, beta = _params(np.random.default_rng(1))
    ev = Evidential(gamma=gamma, nu=nu, alpha=alpha, beta=beta)
    t = [torch.as_tensor(a, dtype=torch.float64) for a in (y, gamma, nu, alpha, beta)]
    np.testing.assert_allclose(ev.nll(y), nig_nll(*t).numpy(), rtol=1e-12)


def test_regularizer_and_loss_follow_design():
    y, gamma, nu, alpha, beta = (torch.tensor([v]) for v in (1.0, 0.5, 2.0, 3.0, 1.0))
    assert float(nig_regularizer(y, gamma, nu, alpha)) == pytest.approx(0.5 * (2 * 2.0 + 3.0))
    loss = evidential_elements(y, gamma, nu, alpha, beta, lam=0.1).mean()
    want = float(nig_nll(y, gamma, nu, alpha, beta)) + 0.1 * 3.5
    assert float(loss) == pytest.approx(want)


def test_variance_power_weighs_each_nll_by_its_variance_held_constant():
    y, gamma, nu, alpha, beta = (
        torch.as_tensor(a, dtype=torch.float64) for a in _params(np.random.default_rng(4))
    )
    variance = beta * (1 + nu) / (nu * (alpha - 1))
    got = evidential_elements(y, gamma, nu, alpha, beta, lam=0.1, power=0.5)
    want = variance**0.5 * nig_nll(y, gamma, nu, alpha, beta) + 0.1 * nig_regularizer(
        y, gamma, nu, alpha
    )
    np.testing.assert_allclose(got.numpy(), want.numpy(), rtol=1e-12)
    grads = []
    for power in (0.0, 0.5):
        g, b = gamma.clone().requires_grad_(True), beta.clone().requires_grad_(True)
        evidential_elements(y, g, nu, alpha, b, lam=0.0, power=power).sum().backward()
        grads.append((g.grad, b.grad))
    # The weight is a constant of the gradient: each gradient is the plain NLL's, scaled.
    for plain, weighed in zip(*grads, strict=True):
        np.testing.assert_allclose(weighed.numpy(), (variance**0.5 * plain).numpy(), rtol=1e-10)


@pytest.mark.parametrize("power", [0.0, 0.5, 1.0])
@pytest.mark.parametrize("scale", [1e-6, 1.0, 1e6])
def test_gradients_finite_at_extreme_inputs(scale, power):
    torch.manual_seed(0)
    raw = (torch.randn(4, 20) * scale).requires_grad_(True)
    gamma = raw[0]  # the network's floors (learner.ensemble)
    nu = torch.nn.functional.softplus(raw[1]) + 1e-6
    alpha = torch.nn.functional.softplus(raw[2]) + (1.0 + 1e-6)
    beta = torch.nn.functional.softplus(raw[3]) + 1e-6
    y = torch.randn(20) * scale
    evidential_elements(y, gamma, nu, alpha, beta, lam=0.01, power=power).mean().backward()
    assert torch.isfinite(raw.grad).all()


@pytest.mark.parametrize("power", [-0.1, 1.5])
def test_variance_power_outside_zero_to_one_is_refused(power):
    with pytest.raises(ConfigError, match="train.nll_variance_power must be in"):
        TrainConfig(nll_variance_power=power)


def test_interval_is_student_t_quantile():
    ev = Evidential(
        gamma=np.array([[1.0]]),
        nu=np.array([[2.0]]),
        alpha=np.array([[3.0]]),
        beta=np.array([[0.5]]),
    )
    lo, hi = ev.interval(0.9)
    scale = np.sqrt(0.5 * 3.0 / (2.0 * 3.0))
    assert hi[0, 0] == pytest.approx(stats.t.ppf(0.95, df=6.0, loc=1.0, scale=scale))
    assert lo[0, 0] == pytest.approx(stats.t.ppf(0.05, df=6.0, loc=1.0, scale=scale))


def test_interval_covers_its_level_on_its_own_distribution():
    rng = np.random.default_rng(3)
    n = 20000
    ev = Evidential(
        gamma=np.zeros((n, 1)),
        nu=np.full((n, 1), 0.7),
        alpha=np.full((n, 1), 2.5),
        beta=np.full((n, 1), 0.2),
    )
    y = stats.t.rvs(df=5.0, scale=ev.scale()[0, 0], size=(n, 1), random_state=rng)
    lo, hi = ev.interval(0.9)
    assert np.mean((y >= lo) & (y <= hi)) == pytest.approx(0.9, abs=0.01)


def test_uncertainties_and_bad_level():
    ev = Evidential(
        gamma=np.zeros((1, 1)),
        nu=np.full((1, 1), 4.0),
        alpha=np.full((1, 1), 3.0),
        beta=np.full((1, 1), 2.0),
    )
    assert ev.aleatoric()[0, 0] == pytest.approx(1.0)
    assert ev.epistemic()[0, 0] == pytest.approx(0.25)
    with pytest.raises(ConfigError, match="level"):
        ev.interval(1.5)


def test_combined_members_keep_aleatoric_and_add_disagreement_to_epistemic():
    from learner.evidential import combine_members

    gen = torch.Generator().manual_seed(0)
    n, m, c = 5, 3, 6
    gamma = torch.randn(n, m * c, generator=gen, dtype=torch.float64)
    nu, alpha, beta = (
        torch.rand(n, m * c, generator=gen, dtype=torch.float64) + low for low in (0.1, 1.5, 0.1)
    )

    def nig(tensors):
        return Evidential(**dict(zip(("gamma", "nu", "alpha", "beta"), tensors, strict=True)))

    each = [
        nig(t.reshape(n, m, c)[:, j].numpy() for t in (gamma, nu, alpha, beta)) for j in range(m)
    ]
    both = nig(t.numpy() for t in combine_members(gamma, nu, alpha, beta, m))
    gammas = np.stack([e.gamma for e in each])
    np.testing.assert_allclose(both.gamma, gammas.mean(0))
    np.testing.assert_allclose(both.aleatoric(), np.mean([e.aleatoric() for e in each], 0))
    expected_epi = np.mean([e.epistemic() for e in each], 0) + gammas.var(0)
    np.testing.assert_allclose(both.epistemic(), expected_epi)
    same = combine_members(*(t[:, :c].repeat(1, m) for t in (gamma, nu, alpha, beta)), m)
    for got, want in zip(same, (gamma[:, :c], nu[:, :c], alpha[:, :c], beta[:, :c]), strict=True):
        torch.testing.assert_close(got, want)
    assert combine_members(gamma, nu, alpha, beta, 1)[0] is gamma
