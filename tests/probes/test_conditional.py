"""Conditional probing on synthetic data whose answer is known, and against scikit-learn."""

from __future__ import annotations

import dataclasses
import math
from pathlib import Path

import numpy as np
import pytest
import torch
from sklearn.linear_model import LogisticRegression
from sklearn.metrics import balanced_accuracy_score
from sklearn.preprocessing import StandardScaler

from vlaprobe.configs.train import ProbeConfig, TrainConfig
from vlaprobe.probes import synthetic_data, train_on_data
from vlaprobe.probes.baselines import predict_baselines, time_bin
from vlaprobe.probes.bootstrap import bootstrap_weights
from vlaprobe.probes.conditional import (
    ConditionalFit,
    adds_beyond,
    baseline_features,
    combined_features,
    conditional_fit,
    evaluate_conditional,
)
from vlaprobe.probes.regularization import ColumnGroups
from vlaprobe.probes.results import ConditionalProbe, read_evaluation
from vlaprobe.probes.split import make_folds, rows_of
from vlaprobe.probes.trainer import fit_probes

TASKS, EPISODES, STEPS, HIDDEN = 4, 6, 40, 12


def _episodes() -> tuple[np.ndarray, np.ndarray]:
    episode_tasks = np.repeat(np.arange(TASKS), EPISODES)
    return np.repeat(np.arange(TASKS * EPISODES), STEPS), episode_tasks


def _split(episode_tasks: np.ndarray, episode: np.ndarray) -> list[tuple[np.ndarray, np.ndarray]]:
    fold = make_folds(episode_tasks, TrainConfig().split, 0)[0]
    return [(rows_of(episode, fold.train), rows_of(episode, fold.test))]


def _conditional(
    hidden: torch.Tensor, labels: np.ndarray, cfg: TrainConfig
) -> tuple[dict[str, ConditionalProbe], dict[str, ConditionalFit], list[tuple[np.ndarray, np.ndarray]]]:
    episode, episode_tasks = _episodes()
    fold_rows = _split(episode_tasks, episode)
    groups = ColumnGroups(episode, episode_tasks, np.zeros(labels.shape[1]), np.ones(labels.shape[1], bool))
    probes = [fit_probes(hidden, labels, train, cfg.probe, 1, groups) for train, _ in fold_rows]
    fits = conditional_fit(hidden, episode, episode_tasks, labels, fold_rows, cfg, probes)
    test = fold_rows[0][1]
    _, groups = np.unique(episode[test], return_inverse=True)
    weights = bootstrap_weights(int(groups.max()) + 1, 300, 2)
    cols = np.arange(labels.shape[1])
    scored = {
        name: evaluate_conditional(f, cols, labels[test], groups, int(groups.max()) + 1, 0.0, weights, [cols])
        for name, f in fits.items()
    }
    return scored, fits, fold_rows


def test_features_are_the_baselines_cells() -> None:
    episode, episode_tasks = _episodes()
    task = baseline_features(episode, episode_tasks, "task")
    cells = baseline_features(episode, episode_tasks, "task_time")
    assert task.shape == (len(episode), TASKS) and cells.shape == (len(episode), TASKS * 10)
    assert (task.sum(1) == 1).all() and (cells.sum(1) == 1).all()
    assert (cells.argmax(1) == episode_tasks[episode] * 10 + time_bin(episode)).all()
    with pytest.raises(ValueError, match="no conditional baseline"):
        baseline_features(episode, episode_tasks, "majority")


def test_labels_of_the_task_alone_gain_nothing() -> None:
    episode, episode_tasks = _episodes()
    rng = np.random.default_rng(0)
    task = episode_tasks[episode]
    labels = np.stack([np.isin(task, [0, 1]), task == 2, np.isin(task, [1, 3])], 1)
    hidden = torch.from_numpy(rng.normal(size=(2, len(episode), HIDDEN)).astype(np.float32))
    probes, _, _ = _conditional(hidden, labels, TrainConfig())
    for p in probes.values():
        assert p.features.value == [1.0]  # the cell decides every atom
        assert all(abs(g) <= 0.01 for g in p.gain.value)
        assert adds_beyond(p) == []


def test_a_hidden_direction_within_each_task_gains_beyond_the_interval() -> None:
    episode, _ = _episodes()
    rng = np.random.default_rng(1)
    noise = rng.normal(size=(2, len(episode), HIDDEN)).astype(np.float32)
    direction = rng.normal(size=(HIDDEN, 2))
    labels = noise[1] @ direction > 0  # only layer 1 carries it; the task and the time say nothing
    probes, _, _ = _conditional(torch.from_numpy(noise), labels, TrainConfig())
    for p in probes.values():
        assert p.features.value[0] < 0.6 and p.combined.value[1] > 0.9
        assert p.gain.low[1] > 0.3 and abs(p.gain.value[0]) < 0.06
        assert adds_beyond(p) == [1]


def test_the_conditional_probe_matches_scikit_learn() -> None:
    episode, episode_tasks = _episodes()
    rng = np.random.default_rng(2)
    noise = rng.normal(size=(1, len(episode), HIDDEN)).astype(np.float32) * 3 + 1
    t = time_bin(episode)
    labels = np.stack([(noise[0, :, 0] + (t > 4) - 0.5 > 0), noise[0] @ rng.normal(size=HIDDEN) > 1], 1)
    cfg = TrainConfig(probe=ProbeConfig(c_grid=(0.5,), tol=1e-6, max_iter=2000))
    probes, fits, fold_rows = _conditional(torch.from_numpy(noise), labels, cfg)
    train, test = fold_rows[0]
    onehot = baseline_features(episode, episode_tasks, "task_time")
    scaler = StandardScaler().fit(noise[0, train])
    x = np.concatenate([scaler.transform(noise[0]), onehot], 1)
    ours = combined_features(torch.from_numpy(noise), train, torch.from_numpy(onehot))[0].numpy()
    np.testing.assert_allclose(ours, x, atol=1e-4)
    # The one-hot block is unpenalised: scikit-learn has one penalty for every feature, so scale those
    # columns by 100 (their penalty in the original units shrinks by 100^2 = 1e4: unpenalised in effect).
    x[:, -onehot.shape[1] :] *= 100
    expected = []
    for a in range(labels.shape[1]):
        model = LogisticRegression(C=0.5, tol=1e-8, max_iter=20000).fit(x[train], labels[train, a])
        expected.append(balanced_accuracy_score(labels[test, a], model.predict(x[test])))
        agree = (fits["task_time"].combined[0, :, a].numpy() > 0) == model.predict(x[test])
        assert agree.mean() > 0.995
    assert probes["task_time"].combined.value[0] == pytest.approx(np.mean(expected), abs=2e-3)
    assert fits["task_time"].c[0, 0] == 0.5 and probes["task_time"].c == [0.5]


def test_the_features_probe_is_close_to_the_cell_majority() -> None:
    episode, episode_tasks = _episodes()
    rng = np.random.default_rng(3)
    t = time_bin(episode)
    labels = np.stack([t >= 5, (t >= 3) & (episode_tasks[episode] == 1), rng.random(len(episode)) < 0.3], 1)
    hidden = torch.from_numpy(rng.normal(size=(1, len(episode), HIDDEN)).astype(np.float32))
    _, fits, fold_rows = _conditional(hidden, labels, TrainConfig(probe=ProbeConfig(c_grid=(1.0,))))
    train, test = fold_rows[0]
    majority = predict_baselines(labels, episode, episode_tasks, train, test)["task_time"]
    predicted = fits["task_time"].features[0].numpy() > 0
    assert (predicted[:, :2] == majority[:, :2]).all()  # deterministic atoms: the cell decides


@pytest.fixture(scope="module")
def trained(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, Path]:
    data = synthetic_data(
        num_tasks=3, episodes_per_task=5, steps_per_episode=30, num_layers=4, hidden_size=32, signal=8.0
    )
    cfg = TrainConfig(bootstrap=200, auprc_bootstrap=0, shuffled_permutations=1, conditional=True)
    on = train_on_data(data, cfg, tmp_path_factory.mktemp("on"))
    off = train_on_data(data, dataclasses.replace(cfg, conditional=False), tmp_path_factory.mktemp("off"))
    assert not TrainConfig().conditional  # off by default in `vlaprobe train`
    return on, off


def test_train_records_conditional_probing_and_can_skip_it(trained: tuple[Path, Path]) -> None:
    on, off = (read_evaluation(p) for p in trained)
    assert "conditional" in on.seconds
    for head, h in on.heads.items():
        assert set(h.conditional()) == {"task", "task_time"}
        for p in h.conditional().values():
            assert len(p.combined.value) == len(on.layers) == len(p.gain.value) == len(p.c)
            assert len(p.features.value) == 1
            assert p.c == h.fit.c and p.c_features is None  # the probes' C; the cells unpenalised
            for i, g in enumerate(p.gain.value):
                if g is not None:
                    assert g == pytest.approx(p.combined.value[i] - p.features.value[0], abs=2e-5)
                    assert p.gain.low[i] <= g <= p.gain.high[i]
        assert off.heads[head].conditional() == {}
        # The probes themselves do not change with conditional probing on.
        assert (
            h.probe["balanced_accuracy"].layer.value == off.heads[head].probe["balanced_accuracy"].layer.value
        )
    assert math.isfinite(on.seconds["conditional"])
