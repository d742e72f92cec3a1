"""The task and time baselines on hand-made data with known answers: ties, cells, deciles, fallbacks."""

from __future__ import annotations

import numpy as np

from vlaprobe.probes.baselines import BASELINES, normalised_time, predict_baselines, time_bin


def test_normalised_time_follows_row_order_within_non_contiguous_episodes() -> None:
    episode = np.array([3, 1, 3, 1, 3, 0])  # episodes interleaved, not sorted, one of length 1
    np.testing.assert_allclose(normalised_time(episode), [0, 0, 1 / 3, 1 / 2, 2 / 3, 0])
    np.testing.assert_array_equal(time_bin(episode), [0, 0, 3, 5, 6, 0])
    np.testing.assert_array_equal(time_bin(episode, bins=2), [0, 0, 0, 1, 1, 0])


def test_time_bins_are_deciles_of_the_episode() -> None:
    np.testing.assert_array_equal(time_bin(np.zeros(20, int)), np.repeat(np.arange(10), 2))
    np.testing.assert_array_equal(time_bin(np.zeros(7, int)), [0, 1, 2, 4, 5, 7, 8])  # floor(10 i / 7)
    assert time_bin(np.zeros(1000, int)).max() == 9 and normalised_time(np.zeros(3, int)).max() < 1


def test_majority_counts_a_tie_as_true() -> None:
    labels = np.array([[1, 1, 1], [1, 0, 0], [0, 0, 0], [0, 0, 1], [1, 1, 0]], bool)
    episode, tasks = np.array([0, 0, 0, 0, 1]), np.array([0, 0])
    pred = predict_baselines(labels, episode, tasks, np.arange(4), np.array([4]))
    # training frequencies 2/4 (a tie: true), 1/4, 2/4 (true)
    np.testing.assert_array_equal(pred["majority"], [[True, False, True]])
    assert set(pred) == set(BASELINES) and pred["majority"].dtype == bool


def test_the_task_baseline_predicts_each_tasks_majority() -> None:
    # task 0 (episodes 0, 1): atom true on 3 of 4 rows; task 1 (episode 2): false on both; overall 3/6 true
    labels = np.array([[1], [1], [1], [0], [0], [0], [0], [1], [0], [1]], bool)
    episode = np.array([0, 0, 1, 1, 2, 2, 3, 3, 4, 4])
    tasks = np.array([0, 0, 1, 0, 1])
    train, test = np.arange(6), np.arange(6, 10)  # test: episode 3 (task 0), episode 4 (task 1)
    pred = predict_baselines(labels, episode, tasks, train, test)
    np.testing.assert_array_equal(pred["task"][:, 0], [True, True, False, False])
    np.testing.assert_array_equal(pred["majority"][:, 0], [True] * 4)  # 3/6: a tie, true


def test_task_time_predicts_the_majority_of_each_task_and_decile() -> None:
    # per task two training episodes of 20 steps and one test episode; task 0 true in the second half of
    # its episodes, task 1 in the first half (one training step of task 1's decile 2 flipped: 3 of its 4
    # rows stay true)
    length = 20
    tasks = np.array([0, 0, 0, 1, 1, 1])
    episode = np.repeat(np.arange(6), length)
    half = np.arange(length) >= length // 2
    labels = np.concatenate([half if t == 0 else ~half for t in tasks])[:, None]
    labels[3 * length + 4] = False  # task 1, decile 2, one of its four training rows
    train = np.flatnonzero(~np.isin(episode, [2, 5]))
    test = np.flatnonzero(np.isin(episode, [2, 5]))
    pred = predict_baselines(labels, episode, tasks, train, test)
    np.testing.assert_array_equal(pred["task_time"][:, 0], labels[test, 0])  # exact: a pure function of time
    # task 0: 20 of 40 training rows true, a tie: true; task 1: 19 of 40, false
    np.testing.assert_array_equal(pred["task"][:, 0], np.repeat([True, False], length))
    np.testing.assert_array_equal(pred["majority"][:, 0], np.zeros(2 * length, bool))  # 39 of 80 true


def test_an_unseen_cell_falls_back_to_the_task_then_to_all() -> None:
    # training: episode 0 (task 0, 2 steps: deciles 0 and 5), episode 1 (task 1, 2 steps)
    # test: episode 2 (task 0, 4 steps: deciles 0, 2, 5, 7; 2 and 7 unseen for task 0), episode 3 (task 2, unseen)
    labels = np.array(
        [
            [1, 1],  # ep 0, decile 0
            [0, 1],  # ep 0, decile 5
            [0, 0],  # ep 1
            [0, 0],  # ep 1
            *[[0, 0]] * 6,  # test rows: their labels are not used
        ],
        bool,
    )
    episode = np.array([0, 0, 1, 1, 2, 2, 2, 2, 3, 3])
    tasks = np.array([0, 1, 0, 2])
    train, test = np.arange(4), np.arange(4, 10)
    pred = predict_baselines(labels, episode, tasks, train, test)
    # atom 0: all-majority 1/4 false; task 0 majority 1/2 true (tie); cells (0, d0) true, (0, d5) false
    np.testing.assert_array_equal(pred["majority"][:, 0], [False] * 6)
    np.testing.assert_array_equal(pred["task"][:, 0], [True] * 4 + [False] * 2)
    np.testing.assert_array_equal(pred["task_time"][:, 0], [True, True, False, True, False, False])
    # atom 1: all 2/4 true (tie); task 0 true, task 1 false; the unseen task 2 gets the overall majority
    np.testing.assert_array_equal(pred["task"][:, 1], [True] * 6)
    np.testing.assert_array_equal(pred["task_time"][:, 1], [True] * 6)

    # the same rows interleaved (each episode's own order kept): the same predictions, row for row
    order = np.array([0, 4, 2, 5, 8, 1, 6, 3, 9, 7])
    position = np.argsort(order)
    new_train, new_test = np.sort(position[train]), np.sort(position[test])
    again = predict_baselines(labels[order], episode[order], tasks, new_train, new_test)
    back = np.argsort(order[new_test])  # test rows of the interleaved run, in the original order
    for name in BASELINES:
        np.testing.assert_array_equal(again[name][back], pred[name])


def test_time_predicts_each_deciles_majority_over_all_tasks_on_an_unseen_task() -> None:
    # held-out task (leave-one-task-out): tasks 0 and 1 train (10 steps each, one row per decile), task 2 tests.
    # The atom is true from decile 6 on in task 0 and from decile 3 on in task 1: deciles 0-2 false in both,
    # 3-5 true in one of two (a tie: true), 6-9 true in both. The task baselines only know the unseen task's
    # fallback, the overall majority (13 of 20 true: true everywhere).
    length = 10
    tasks = np.array([0, 1, 2])
    episode = np.repeat(np.arange(3), length)
    step = np.arange(length)
    labels = np.concatenate([step >= 6, step >= 3, np.zeros(length, bool)])[:, None]
    train, test = np.arange(2 * length), np.arange(2 * length, 3 * length)
    pred = predict_baselines(labels, episode, tasks, train, test)
    np.testing.assert_array_equal(pred["time"][:, 0], step >= 3)
    for name in ("majority", "task", "task_time"):
        np.testing.assert_array_equal(pred[name][:, 0], np.ones(length, bool))


def test_time_ignores_the_task_where_task_time_does_not() -> None:
    # two tasks with opposite time courses: the time cells mix them (ties: true), task x time separates them
    length = 10
    tasks = np.array([0, 1, 0, 1])
    episode = np.repeat(np.arange(4), length)
    late = np.arange(length) >= 5
    labels = np.concatenate([late, ~late, late, ~late])[:, None]
    train, test = np.arange(2 * length), np.arange(2 * length, 4 * length)
    pred = predict_baselines(labels, episode, tasks, train, test)
    np.testing.assert_array_equal(pred["time"][:, 0], np.ones(2 * length, bool))
    np.testing.assert_array_equal(pred["task_time"][:, 0], labels[test, 0])


def test_majorities_count_only_the_rows_that_define_the_atom() -> None:
    """Atom 0 is undefined (stored false) in episode 0, so its majority is that of episode 1 alone (true);
    atom 1, defined nowhere in training, falls back to false."""
    labels = np.array([[0, 0], [0, 0], [0, 0], [1, 0], [1, 0], [0, 0], [0, 0], [0, 0]], bool)
    episode = np.array([0, 0, 0, 1, 1, 1, 2, 2])
    defined = np.ones_like(labels)
    defined[:3, 0] = False
    defined[:6, 1] = False
    train, test = np.arange(6), np.arange(6, 8)
    plain = predict_baselines(labels, episode, np.zeros(3, int), train, test)
    pred = predict_baselines(labels, episode, np.zeros(3, int), train, test, defined=defined)
    np.testing.assert_array_equal(plain["majority"], [[False, False]] * 2)  # 2 of 6 true
    np.testing.assert_array_equal(pred["majority"], [[True, False]] * 2)  # 2 of 3 defined rows true
    np.testing.assert_array_equal(pred["time"][:, 1], [False, False])
