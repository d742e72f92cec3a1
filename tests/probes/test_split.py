"""Episode split (stratified, k-fold, leak check) and the training-split label filter."""

from __future__ import annotations

import numpy as np
import pytest

from vlaprobe.probes.split import check_no_leak, filter_labels, rows_of, search_folds, split_episodes


def test_holdout_is_stratified_by_task_and_disjoint() -> None:
    tasks = np.repeat(np.arange(5), [10, 10, 5, 2, 1])
    (fold,) = split_episodes(tasks, test_fraction=0.2, folds=1, seed=3)
    assert len(np.intersect1d(fold.train, fold.test)) == 0
    assert sorted(np.concatenate([fold.train, fold.test]).tolist()) == list(range(len(tasks)))
    per_task = {t: int((tasks[fold.test] == t).sum()) for t in range(5)}
    # round(0.2 n) held out, at least one when a task has >= 2 episodes, never all of them
    assert per_task == {0: 2, 1: 2, 2: 1, 3: 1, 4: 0}
    # every task with a test episode also has training episodes
    for t in range(4):
        assert (tasks[fold.train] == t).any()


def test_holdout_depends_on_seed_only() -> None:
    tasks = np.repeat(np.arange(3), 8)
    a = split_episodes(tasks, 0.25, 1, seed=0)[0].test
    b = split_episodes(tasks, 0.25, 1, seed=0)[0].test
    c = split_episodes(tasks, 0.25, 1, seed=1)[0].test
    assert np.array_equal(a, b)
    assert not np.array_equal(a, c)


def test_kfold_tests_every_episode_exactly_once_with_even_folds() -> None:
    tasks = np.repeat(np.arange(4), [7, 5, 3, 1])
    folds = split_episodes(tasks, 0.2, folds=4, seed=0)
    tested = np.concatenate([f.test for f in folds])
    assert sorted(tested.tolist()) == list(range(len(tasks)))
    sizes = [len(f.test) for f in folds]
    assert max(sizes) - min(sizes) <= 1
    for f in folds:
        assert len(np.intersect1d(f.train, f.test)) == 0
        assert len(f.train) + len(f.test) == len(tasks)


def test_split_refuses_impossible_requests() -> None:
    with pytest.raises(ValueError):
        split_episodes(np.zeros(3, int), 0.2, folds=5, seed=0)
    with pytest.raises(ValueError):
        split_episodes(np.zeros(3, int), 1.0, folds=1, seed=0)


def test_leak_check_catches_a_shared_episode() -> None:
    episode = np.repeat(np.arange(4), 3)
    train = rows_of(episode, np.array([0, 1, 2]))
    test = rows_of(episode, np.array([3]))
    check_no_leak(episode, train, test)  # clean split passes
    with pytest.raises(AssertionError, match="leak"):
        check_no_leak(episode, np.append(train, test[0]), test)  # one test frame in training


def test_filter_drops_exactly_the_near_constant_atoms() -> None:
    n = 1000
    freqs = [0.0, 0.005, 0.01, 0.3, 0.99, 0.995, 1.0]
    y = np.zeros((n, len(freqs)), bool)
    for j, f in enumerate(freqs):
        y[: round(f * n), j] = True
    names = [f"a{j}" for j in range(len(freqs))]
    result = filter_labels(y, names, 0.01, 0.99)
    assert result.kept.tolist() == [2, 3, 4]  # the thresholds themselves are kept
    dropped = {d["atom"]: d for d in result.dropped}
    assert sorted(dropped) == ["a0", "a1", "a5", "a6"]
    assert "< 1%" in dropped["a1"]["reason"] and "> 99%" in dropped["a5"]["reason"]
    assert dropped["a1"]["train_frequency"] == pytest.approx(0.005)


def test_filter_over_folds_drops_an_atom_any_fold_would_drop() -> None:
    a = np.array([[1, 1]] * 50 + [[0, 1]] * 50, bool)  # column 1 constant in this fold
    b = np.array([[1, 0]] * 50 + [[0, 1]] * 50, bool)
    result = filter_labels([a, b], ["x", "y"], 0.01, 0.99)
    assert result.kept.tolist() == [0]
    assert result.dropped[0]["atom"] == "y" and result.dropped[0]["train_frequency"] == 1.0


def test_search_folds_hold_out_only_episodes_whose_task_stays_in_training() -> None:
    tasks = np.array([0, 0, 1, 1, 1, 2, 3])  # tasks 2 and 3 have one training episode each
    folds = search_folds(tasks, 3, seed=0, across_tasks=False)
    assert len(folds) == 3
    held = np.concatenate([f.test for f in folds])
    assert sorted(held.tolist()) == [0, 1, 2, 3, 4]  # every episode of a task with >= 2, once
    for f in folds:
        assert {5, 6} <= set(f.train.tolist())  # the single episodes train in every fold
        assert set(tasks[f.test]) <= set(tasks[f.train])  # a held-out episode's task is trained on
        assert not set(f.test) & set(f.train)
    # where every task has >= 2 episodes the folds are split_episodes' own
    even = np.repeat(np.arange(4), 2)
    same = split_episodes(even, 0.5, 3, 7)
    for a, b in zip(search_folds(even, 3, 7, False), same, strict=True):
        assert a.test.tolist() == b.test.tolist() and a.train.tolist() == b.train.tolist()


def test_search_folds_are_empty_when_nothing_can_be_held_out() -> None:
    assert search_folds(np.arange(10), 3, seed=0, across_tasks=False) == []  # one episode per task
    pair = search_folds(np.array([0, 1, 2, 2]), 3, 0, False)  # one task with 2 episodes: 2 folds of it
    assert [f.test.tolist() for f in pair] in ([[2], [3]], [[3], [2]])
    assert search_folds(np.zeros(6, int), 3, 0, across_tasks=True) == []  # one task


def test_search_folds_across_tasks_hold_out_whole_tasks() -> None:
    tasks = np.repeat(np.arange(5), 2)
    folds = search_folds(tasks, 3, seed=1, across_tasks=True)
    assert len(folds) == 3
    assert sorted(np.concatenate([f.test for f in folds]).tolist()) == list(range(10))
    for f in folds:
        assert not set(tasks[f.test]) & set(tasks[f.train])
