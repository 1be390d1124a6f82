"""The hyperparameter search: space, shared resumable study, pruning, selection, CLI, workers.

Trials train real (tiny) evidential ensembles on a small dataset whose labels are the real pose
errors of a UR10 with perturbed DH lengths against its nominal pinocchio model.
"""

from __future__ import annotations

import dataclasses
import json
import os
import socket
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import optuna
import pandas as pd
import pytest
from optuna.distributions import IntDistribution
from optuna.trial import TrialState, create_trial

from kinematics.dataset import Dataset, DatasetMeta, write_dataset
from kinematics.description import load_description
from kinematics.errors import ConfigError
from kinematics.model import RobotModel
from kinematics.transforms import xyz_quat_from_transform
from learner.config import ModelConfig, TrainConfig
from learner.hpo import HpoConfig, cv_folds, dataset_arrays, search
from learner.hpo_space import SearchSpace, learner_defaults, load_space, space_from_dict, suggest
from learner.hpo_study import (
    WORKER_ATTR,
    fail_stale_trials,
    lock_path,
    make_study,
    open_storage,
    run_trials,
    select_trial,
)
from learner.snapshot import load_snapshot
from stream.cli import main

optuna.logging.set_verbosity(optuna.logging.WARNING)
TINY = SearchSpace(
    hidden_layers=(1, 2),
    neurons=(4, 16),
    batch_size=(8, 32),
    lr=(1e-3, 1e-2),
    weight_decay=(1e-7, 1e-3),
)
TINY_TOML = """
hidden_layers = [1, 2]
neurons = [4, 16]
batch_size = [8, 32]
lr = [1e-3, 1e-2]
weight_decay = [1e-7, 1e-3]
"""


def toy_dataset(n: int = 80, seed: int = 0) -> Dataset:
    """UR10 poses measured on a 'true' arm whose lengths and offsets differ from nominal."""
    nominal = load_description("ur10")
    joints = tuple(
        dataclasses.replace(
            j,
            a_m=j.a_m + 0.001 * (i % 2),
            d_m=j.d_m + 0.002 * (i % 3 == 0),
            offset_deg=j.offset_deg + 0.02 * (i % 2 == 0),
        )
        for i, j in enumerate(nominal.joints)
    )
    true = dataclasses.replace(nominal, joints=joints)
    q = np.random.default_rng(seed).uniform(-np.pi, np.pi, size=(n, 6))
    xyz, quat = xyz_quat_from_transform(RobotModel(true).fk(q))
    table = pd.DataFrame(q, columns=[f"q{i}" for i in range(1, 7)])
    table.insert(0, "t", np.arange(n, dtype=float))
    table[["x", "y", "z"]] = xyz
    table[["qx", "qy", "qz", "qw"]] = quat
    return Dataset(table, DatasetMeta(robot="ur10"))


@pytest.fixture(scope="module")
def arrays():
    return dataset_arrays(toy_dataset())


def test_default_space_is_designs():
    s = SearchSpace()
    assert (s.hidden_layers, s.neurons, s.batch_size) == ((1, 15), (50, 500), (4, 64))
    assert (s.lr, s.weight_decay, s.dropout) == ((1e-7, 1e-2), (1e-7, 1e-2), (0.0, 0.5))
    assert s.activations == ("elu", "relu", "gelu")


def test_space_from_toml_overrides_only_named_ranges(tmp_path):
    path = tmp_path / "space.toml"
    path.write_text(TINY_TOML + 'activations = ["gelu"]\n')
    s = load_space(path)
    assert s.neurons == (4, 16) and s.activations == ("gelu",) and s.dropout == (0.0, 0.5)


@pytest.mark.parametrize(
    "raw, match",
    [
        ({"neurons": [64, 32]}, r"space.neurons must satisfy low <= high.*\[64, 32\]"),
        ({"hidden_layers": [0, 3]}, r"space.hidden_layers .*low >= 1"),
        ({"lr": [0.0, 1e-2]}, r"space.lr is log-scaled and must be > 0"),
        ({"dropout": [0.1, 1.0]}, r"space.dropout must stay below 1"),
        ({"activations": ["tanh"]}, r"space.activations .* got \['tanh'\]"),
        ({"neurons": [1.5, 8]}, r"space.neurons must be two integers"),
        ({"neurons": [8]}, r"space.neurons must be \[low, high\]"),
        ({"layers": [1, 2]}, r"unknown search-space key\(s\) \['layers'\]"),
    ],
)
def test_bad_space_raises_one_line(raw, match):
    with pytest.raises(ConfigError, match=match):
        space_from_dict(raw)


def test_bad_space_file_names_the_file(tmp_path):
    path = tmp_path / "space.toml"
    path.write_text("neurons = [64, 32]\n")
    with pytest.raises(ConfigError, match=r"space.toml: space.neurons"):
        load_space(path)
    with pytest.raises(ConfigError, match="not found"):
        load_space(tmp_path / "none.toml")


@pytest.mark.parametrize(
    "kwargs, match",
    [({"folds": 1}, "hpo.folds"), ({"trials": 0}, "hpo.trials"), ({"timeout_s": 0}, "timeout")],
)
def test_bad_config_raises(kwargs, match):
    with pytest.raises(ConfigError, match=match):
        HpoConfig(**kwargs)


def test_folds_partition_the_points():
    folds = cv_folds(23, 5, seed=3)
    assert sorted(np.concatenate(folds).tolist()) == list(range(23))
    assert [f.tolist() for f in folds] == [f.tolist() for f in cv_folds(23, 5, seed=3)]


def test_search_prunes_with_real_training(arrays, tmp_path):
    spec, X, Y = arrays
    cfg = HpoConfig(
        trials=10, folds=2, max_epochs=4, min_epochs=1, startup_trials=3, top_k=3, seed=0
    )
    out = tmp_path / "model.safetensors"
    result = search(spec, X, Y, cfg, tmp_path / "hpo.journal", space=TINY, out=out, robot="ur10")
    study = optuna.load_study(study_name=cfg.study, storage=open_storage(tmp_path / "hpo.journal"))
    states = [t.state for t in study.trials]
    assert len(states) == 10 and states.count(TrialState.PRUNED) >= 1
    assert result.pruned == states.count(TrialState.PRUNED) and result.ran_here == 10
    complete = [t for t in study.trials if t.state == TrialState.COMPLETE]
    # the last report of a complete trial is its score: the mean over folds of each fold's min
    for t in complete:
        assert t.intermediate_values[max(t.intermediate_values)] == pytest.approx(t.value)
    top = sorted(complete, key=lambda t: t.value)[:3]
    close = [t for t in top if t.value <= 1.1 * top[0].value]
    assert result.selected.n_weights == min(t.user_attrs["n_weights"] for t in close)
    assert [r.number for r in result.top] == [t.number for t in top]
    assert f"*{result.selected.number:>6}" in result.table()
    assert json.loads(json.dumps(result.to_dict()))["selected"]["number"] == result.selected.number
    loaded = load_snapshot(out)
    assert loaded.n_weights == result.selected.n_weights
    np.testing.assert_array_equal(loaded.predict(X).gamma, result.model.predict(X).gamma)


def test_stopped_study_resumes_without_repeats(arrays, tmp_path):
    spec, X, Y = arrays
    cfg = HpoConfig(trials=3, folds=2, max_epochs=2, min_epochs=1, top_k=2, seed=0)
    first = search(spec, X, Y, cfg, tmp_path / "hpo.journal", space=TINY)
    again = search(
        spec, X, Y, dataclasses.replace(cfg, trials=5), tmp_path / "hpo.journal", space=TINY
    )
    assert first.ran_here == 3 and again.ran_here == 2
    assert again.complete + again.pruned == 5
    study = optuna.load_study(study_name=cfg.study, storage=open_storage(tmp_path / "hpo.journal"))
    assert sorted(t.number for t in study.trials) == [0, 1, 2, 3, 4]
    params = {tuple(sorted(t.params.items())) for t in study.trials}
    assert len(params) == 5


def test_sqlite_study_resumes(tmp_path):
    url = f"sqlite:///{tmp_path}/hpo.db"

    def objective(trial: optuna.Trial) -> float:
        return trial.suggest_float("x", 0.0, 1.0)

    for total, ran in [(3, [0, 1, 2]), (5, [3, 4])]:
        study = make_study(open_storage(url), "s", seed=0, max_resource=1)
        seen = []
        assert run_trials(study, objective, total, lock=lock_path(url), on_trial=seen.append) == ran
        # reported once as the study opens (a resumed one at its count), then after each trial
        assert [(p.finished, p.trial is None) for p in seen] == [(ran[0], True)] + [
            (n + 1, False) for n in ran
        ]
    assert len({t.params["x"] for t in study.trials}) == 5
    assert lock_path(url) == tmp_path / "hpo.db.hpo-lock"


def test_same_seed_repeats_the_search(arrays, tmp_path):
    spec, X, Y = arrays
    cfg = HpoConfig(trials=3, folds=2, max_epochs=2, min_epochs=1, top_k=2, seed=7)
    runs = [search(spec, X, Y, cfg, tmp_path / f"{k}.journal", space=TINY) for k in range(2)]
    assert runs[0].top == runs[1].top
    np.testing.assert_array_equal(runs[0].model.predict(X).gamma, runs[1].model.predict(X).gamma)


def test_timeout_stops_asking_for_trials(tmp_path):
    study = make_study(open_storage(tmp_path / "j.journal"), "s", seed=0, max_resource=1)

    def slow(trial: optuna.Trial) -> float:
        time.sleep(0.2)
        return trial.suggest_float("x", 0.0, 1.0)

    assert run_trials(study, slow, 10, timeout_s=0.1) == [0]
    assert len(study.trials) == 1


def test_selection_prefers_fewest_weights_among_top_k():
    study = optuna.create_study()
    trials = [(0.1, 900), (0.2, 300), (0.3, 100), (0.05, 5000), (0.9, 10), (float("inf"), 1)]
    for value, n_weights in trials:
        study.add_trial(
            create_trial(
                value=value,
                params={"x": 1},
                distributions={"x": IntDistribution(0, 2)},
                user_attrs={"n_weights": n_weights},
            )
        )
    inf = float("inf")
    assert select_trial(study, top_k=4, within=inf).user_attrs["n_weights"] == 100
    assert select_trial(study, top_k=1, within=inf).user_attrs["n_weights"] == 5000
    assert select_trial(study, top_k=10, within=inf).user_attrs["n_weights"] == 10  # never inf
    # only trials scoring within 10 % / 100 % / 300 % of the best (0.05) compete on size
    assert select_trial(study, top_k=10).user_attrs["n_weights"] == 5000
    assert select_trial(study, top_k=10, within=1.0).user_attrs["n_weights"] == 900
    assert select_trial(study, top_k=10, within=3.0).user_attrs["n_weights"] == 300
    with pytest.raises(ConfigError, match="no complete trial"):
        select_trial(optuna.create_study(), top_k=3)


def test_learner_defaults_run_first_and_once(tmp_path):
    first = learner_defaults(SearchSpace())
    assert first == {
        "hidden_layers": ModelConfig().hidden_layers,
        "neurons": ModelConfig().neurons,
        "activation": ModelConfig().activation,
        "batch_size": TrainConfig().batch_size,
        "lr": TrainConfig().lr,
        "weight_decay": TrainConfig().weight_decay,
        "dropout": ModelConfig().dropout,
    }
    assert learner_defaults(TINY) is None  # 64 neurons lie outside TINY's 4..16

    def objective(trial: optuna.Trial) -> float:
        return suggest(trial, SearchSpace()).lr

    storage = open_storage(tmp_path / "j.journal")
    for total in (2, 4):  # a resume (or a second worker) must not enqueue the defaults again
        study = make_study(storage, "s", seed=0, max_resource=1)
        run_trials(study, objective, total, lock=tmp_path / "lock", first=first)
    assert [t.params == first for t in study.trials] == [True, False, False, False]


def test_running_trial_of_a_dead_worker_is_failed(tmp_path):
    study = make_study(open_storage(tmp_path / "j.journal"), "s", seed=0, max_resource=4)
    dead = subprocess.Popen([sys.executable, "-c", "pass"])
    dead.wait()
    trial = study.ask()
    trial.set_user_attr(WORKER_ATTR, f"{socket.gethostname()}:{dead.pid}")
    alive = study.ask()
    alive.set_user_attr(WORKER_ATTR, f"{socket.gethostname()}:{os.getpid()}")
    assert fail_stale_trials(study) == [trial.number]
    assert study.trials[alive.number].state == TrialState.RUNNING


def test_cli_rejects_bad_input_with_exit_2(tmp_path, capsys):
    assert main(["hpo", "--data", str(tmp_path / "none.parquet")]) == 2
    assert "no such dataset file" in capsys.readouterr().err
    (tmp_path / "s.toml").write_text("neurons = [9, 3]\n")
    data = write_dataset(toy_dataset(20), tmp_path / "d.parquet")
    assert main(["hpo", "--data", str(data), "--space", str(tmp_path / "s.toml")]) == 2
    assert "space.neurons" in capsys.readouterr().err


@pytest.mark.integration
def test_two_worker_processes_share_one_journal(tmp_path):
    data = write_dataset(toy_dataset(80), tmp_path / "d.parquet")
    # batches of 64: each worker's final retrain (up to 1,500 epochs on 72 points) takes 2
    # steps an epoch, not 9
    (tmp_path / "space.toml").write_text(TINY_TOML.replace("[8, 32]", "[64, 64]"))
    journal = tmp_path / "shared.journal"
    robocal = Path(sys.executable).parent / "robocal"
    workers = [
        subprocess.Popen(
            [
                str(robocal), "hpo", "--data", str(data), "--trials", "6",
                "--storage", str(journal), "--space", str(tmp_path / "space.toml"),
                # 200 epochs: a trial takes 1.3-1.7 s alone, so both workers start one before the
                # six run out (at 6 epochs all six ran in 0.3 s and one worker could take them all)
                "--folds", "2", "--epochs", "200", "--no-prune", "--json",
                "--out", str(tmp_path / f"m{k}.safetensors"),
            ],
            stdout=subprocess.PIPE,
            stderr=subprocess.PIPE,
            text=True,
            env={"OMP_NUM_THREADS": "1", "PATH": str(robocal.parent)},
        )
        for k in range(2)
    ]  # fmt: skip
    deadline = time.monotonic() + 300
    outputs = [w.communicate(timeout=max(1, deadline - time.monotonic())) for w in workers]
    assert [w.returncode for w in workers] == [0, 0], [o[1][-500:] for o in outputs]
    reports = [json.loads(o[0]) for o in outputs]
    # 6 between them, not 6 each: they share the study (which one runs more is a race)
    assert sum(r["ran_here"] for r in reports) == 6
    assert all(Path(r["snapshot"]).is_file() for r in reports)
    study = optuna.load_study(study_name="robocal-hpo", storage=open_storage(journal))
    assert len(study.trials) == 6
    assert all(t.state == TrialState.COMPLETE for t in study.trials)
    by_worker = {t.user_attrs[WORKER_ATTR] for t in study.trials}
    assert len(by_worker) == 2
    assert {f"{w.pid}" for w in workers} == {b.rpartition(":")[2] for b in by_worker}


def test_bad_storage_raises_config_error(tmp_path):
    with pytest.raises(ConfigError, match=r"storage notadb://x: cannot open"):
        open_storage("notadb://x")
    with pytest.raises(ConfigError, match="expected a journal file, got a folder"):
        open_storage(tmp_path)
