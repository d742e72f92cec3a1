"""Predictors that know the task and the time but see no hidden state: what a probe must beat.

Each is fit on training rows and predicts test rows, per atom, the majority class of a cell:

- ``majority``: one cell (the per-atom training majority);
- ``time``: the decile of the row's normalised episode time (step / episode length), whatever the task: the
  comparator of held-out tasks (``--split leave-one-task-out``), where the task cells were never seen;
- ``task``: the row's task;
- ``task_time``: the row's task and its time decile.

A cell never seen in training falls back to the coarser one (time -> all; task x time -> task -> all). Ties count as
true (frequency >= 0.5), as the majority baseline always did. Plain numpy on labels and episode
bookkeeping, so any store (or any other labels) can be scored the same way::

    from vlaprobe.probes.baselines import predict_baselines
    pred = predict_baselines(labels, episode, episode_tasks, train_rows, test_rows)
    pred["task_time"]        # bool (test rows, atoms)
"""

from __future__ import annotations

import numpy as np

BASELINES = ("majority", "time", "task", "task_time")
"""The baselines, coarsest first (``time`` and ``task`` are both one step finer than ``majority``)."""
TIME_BINS = 10
"""Deciles of normalised episode time."""


def normalised_time(episode: np.ndarray) -> np.ndarray:
    """Per row: its position within its episode divided by the episode's length, in [0, 1).

    Rows of an episode are taken in row order (they need not be contiguous)."""
    episode = np.asarray(episode)
    order = np.argsort(episode, kind="stable")
    sorted_ep = episode[order]
    starts = np.flatnonzero(np.r_[True, sorted_ep[1:] != sorted_ep[:-1]])
    lengths = np.diff(np.r_[starts, len(episode)])
    first = np.repeat(starts, lengths)
    out = np.empty(len(episode))
    out[order] = (np.arange(len(episode)) - first) / np.repeat(lengths, lengths)
    return out


def time_bin(episode: np.ndarray, bins: int = TIME_BINS) -> np.ndarray:
    """Per row: the bin (0 .. bins - 1) of its normalised episode time."""
    return np.minimum((normalised_time(episode) * bins).astype(np.int64), bins - 1)


def task_time_cell(episode: np.ndarray, episode_tasks: np.ndarray, bins: int = TIME_BINS) -> np.ndarray:
    """Per row: its task x time cell, task x ``bins`` + the bin of its normalised episode time (the cells of
    the ``task_time`` baseline and of the matched-steps control)."""
    task = np.asarray(episode_tasks)[np.asarray(episode)]
    return task * bins + time_bin(episode, bins)


def _true_share(labels: np.ndarray, defined: np.ndarray | None) -> tuple[np.ndarray, np.ndarray]:
    """Per atom: the share of true rows among the rows where it is defined, and whether any row defines it."""
    if defined is None:
        return labels.mean(0), np.full(labels.shape[1], len(labels) > 0)
    n = defined.sum(0)
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.where(n > 0, (labels & defined).sum(0) / n, 0.0), n > 0


def _cell_majority(
    labels: np.ndarray,
    cells: np.ndarray,
    test_cells: np.ndarray,
    fallback: np.ndarray,
    defined: np.ndarray | None = None,
) -> np.ndarray:
    """Per test row: the training majority of its cell, or ``fallback``'s row where the cell is unseen (or, with
    ``defined``, where no row of the cell defines the atom)."""
    out = fallback.copy()
    for cell in np.unique(test_cells):
        members = cells == cell
        if members.any():
            share, seen = _true_share(labels[members], None if defined is None else defined[members])
            rows = np.flatnonzero(test_cells == cell)
            out[np.ix_(rows, np.flatnonzero(seen))] = share[seen] >= 0.5
    return out


def predict_baselines(
    labels: np.ndarray,
    episode: np.ndarray,
    episode_tasks: np.ndarray,
    train_rows: np.ndarray,
    test_rows: np.ndarray,
    bins: int = TIME_BINS,
    defined: np.ndarray | None = None,
) -> dict[str, np.ndarray]:
    """Predictions of every baseline for ``test_rows``, fit on ``train_rows``.

    ``labels`` bool (rows, atoms); ``episode`` int (rows,) episode position of each row; ``episode_tasks``
    int (episodes,) the task of each episode. ``defined`` bool (rows, atoms), when given: a majority counts
    only the training rows that define the atom (an atom undefined in a row's task is no evidence either way).
    Returns baseline name -> bool (test rows, atoms).
    """
    labels = np.asarray(labels, bool)
    task = np.asarray(episode_tasks)[np.asarray(episode)]
    train_y = labels[train_rows]
    train_d = None if defined is None else np.asarray(defined, bool)[train_rows]
    share, _ = _true_share(train_y, train_d)
    majority = np.broadcast_to(share >= 0.5, (len(test_rows), labels.shape[1])).copy()
    when = time_bin(episode, bins)
    by_time = _cell_majority(train_y, when[train_rows], when[test_rows], majority, train_d)
    by_task = _cell_majority(train_y, task[train_rows], task[test_rows], majority, train_d)
    cell = task_time_cell(episode, episode_tasks, bins)
    by_task_time = _cell_majority(train_y, cell[train_rows], cell[test_rows], by_task, train_d)
    return {"majority": majority, "time": by_time, "task": by_task, "task_time": by_task_time}
