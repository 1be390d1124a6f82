import pytest

from kinematics.errors import ConfigError
from learner.config import ContinualConfig, ModelConfig, TrainConfig


@pytest.mark.parametrize(
    "make, field",
    [
        (lambda: ModelConfig(hidden_layers=0), "hidden_layers"),
        (lambda: ModelConfig(neurons=2.5), "neurons"),
        (lambda: ModelConfig(activation="tanh"), "activation"),
        (lambda: ModelConfig(dropout=1.0), "dropout"),
        (lambda: TrainConfig(batch_size=0), "batch_size"),
        (lambda: TrainConfig(lr=0.0), "lr"),
        (lambda: TrainConfig(patience_lr=0), "patience_lr"),
        (lambda: TrainConfig(val_fraction=1.0), "val_fraction"),
        (lambda: TrainConfig(lam=-1.0), "lam"),
        (lambda: ContinualConfig(memory=0), "memory"),
        (lambda: ContinualConfig(strategy="lru"), "strategy"),
    ],
)
def test_bad_values_name_the_field(make, field):
    with pytest.raises(ConfigError, match=field):
        make()


def test_defaults_follow_the_method():
    t = TrainConfig()
    assert t.patience_lr == 30
    c = ContinualConfig()
    # DESIGN's reference experiment streams N_m 500; the default memory is the measured 4,000
    assert (c.memory, c.batch, c.init, c.strategy) == (4000, 100, 50, "max_error")
