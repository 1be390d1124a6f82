import pytest
import torch

from kinematics.errors import ConfigError
from learner.ensemble import PER_HEAD_ROWS, EvidentialEnsemble


def _net(**kw):
    return EvidentialEnsemble(n_inputs=5, hidden_layers=2, neurons=8, seed=kw.pop("seed", 0), **kw)


def test_outputs_respect_nig_constraints():
    x = torch.randn(30, 5, generator=torch.Generator().manual_seed(0)) * 1e4
    gamma, nu, alpha, beta = _net()(x)
    assert gamma.shape == (30, 6)
    assert (nu > 0).all() and (beta > 0).all() and (alpha > 1).all()


def test_heads_are_independent():
    net = _net()
    x = torch.randn(10, 5)
    gamma, *_ = net(x)
    gamma[:, 2].sum().backward()
    for w in net.weights:
        grads = w.grad.abs().sum(dim=(1, 2))
        assert grads[2] > 0
        assert torch.all(grads[[0, 1, 3, 4, 5]] == 0)


@pytest.mark.parametrize(
    "training, rows", [(True, PER_HEAD_ROWS), (False, 7), (False, PER_HEAD_ROWS)]
)
def test_matches_six_separate_mlps(training, rows):
    # Few rows, or training, take the batched path; evaluating many rows goes head by head.
    net = _net(activation="relu").train(training)
    x = torch.randn(rows, 5)
    gamma, nu, alpha, beta = net(x)
    for head in range(6):
        h = x
        for i, (w, b) in enumerate(zip(net.weights, net.biases, strict=True)):
            h = h @ w[head] + b[head, 0]
            if i < len(net.weights) - 1:
                h = torch.relu(h)
        torch.testing.assert_close(gamma[:, head], h[:, 0])
        want_alpha = torch.nn.functional.softplus(h[:, 2]) + 1 + 1e-6
        torch.testing.assert_close(alpha[:, head], want_alpha)


def test_seeded_initialisation_is_reproducible():
    a, b, c = _net(seed=1), _net(seed=1), _net(seed=2)
    assert all(torch.equal(p, q) for p, q in zip(a.parameters(), b.parameters(), strict=True))
    assert not torch.equal(a.weights[0], c.weights[0])


def test_dropout_only_in_training():
    net = _net(dropout=0.5)
    x = torch.randn(20, 5)
    net.eval()
    torch.testing.assert_close(net(x)[0], net(x)[0])
    net.train()
    assert not torch.equal(net(x)[0], net(x)[0])


def test_bad_activation_is_a_config_error():
    with pytest.raises(ConfigError, match="activation"):
        _net(activation="tanh")
