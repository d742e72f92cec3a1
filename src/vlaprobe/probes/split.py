"""Train/test division by whole episodes, stratified by task, and the label filter on the training split."""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

if TYPE_CHECKING:
    from vlaprobe.configs.train import SplitConfig


@dataclass(frozen=True)
class Fold:
    """One train/test division: episode positions on each side."""

    train: np.ndarray
    """Sorted episode positions used for training."""
    test: np.ndarray
    """Sorted episode positions held out."""


def split_episodes(episode_tasks: np.ndarray, test_fraction: float, folds: int, seed: int) -> list[Fold]:
    """Divide episodes into train and test, task by task, so every task is on both sides when it can be.

    ``folds == 1``: each task with n >= 2 episodes holds out round(test_fraction * n) of them, at least 1 and
    at most n - 1 (a task with one episode trains only). ``folds >= 2``: each task's shuffled episodes are
    dealt in turn to the folds (continuing where the previous task stopped, so fold sizes stay even); fold k
    tests its episodes and trains on all others.
    """
    tasks = np.asarray(episode_tasks)
    num = len(tasks)
    if folds < 1:
        raise ValueError(f"folds must be >= 1, got {folds}")
    if folds == 1 and not 0.0 < test_fraction < 1.0:
        raise ValueError(f"test_fraction must be in (0, 1), got {test_fraction}")
    if folds > num:
        raise ValueError(f"{folds} folds need at least {folds} episodes, there are {num}")
    rng = np.random.default_rng(seed)
    if folds == 1:
        test: list[int] = []
        for task in np.unique(tasks):
            members = rng.permutation(np.flatnonzero(tasks == task))
            if len(members) >= 2:
                k = min(max(round(test_fraction * len(members)), 1), len(members) - 1)
                test.extend(members[:k].tolist())
        test_arr = np.sort(np.array(test, np.int64))
        return [Fold(train=np.setdiff1d(np.arange(num), test_arr), test=test_arr)]
    assignment = np.empty(num, np.int64)
    turn = int(rng.integers(folds))
    for task in np.unique(tasks):
        members = rng.permutation(np.flatnonzero(tasks == task))
        assignment[members] = (turn + np.arange(len(members))) % folds
        turn = (turn + len(members)) % folds
    return [
        Fold(train=np.flatnonzero(assignment != k), test=np.flatnonzero(assignment == k))
        for k in range(folds)
    ]


def search_folds(episode_tasks: np.ndarray, folds: int, seed: int, across_tasks: bool) -> list[Fold]:
    """Folds of the training episodes for choosing a hyper-parameter, shaped like the split that scores it.

    Within tasks (the default ``--split episode``, whose test episodes come from the training tasks): only
    episodes of tasks with at least 2 training episodes are held out, dealt as :func:`split_episodes` does, so
    every held-out episode's task is also in its fold's training; the episodes of a task with one training
    episode train in every fold (holding one out would test an unseen task, a harder question than the test
    split asks). ``across_tasks`` (``--split leave-one-task-out``): whole tasks are held out, dealt to the
    folds in turn. At most ``folds`` folds; none when fewer than 2 units (episodes or tasks) can be held out.
    """
    tasks = np.asarray(episode_tasks)
    rng = np.random.default_rng(seed)
    everyone = np.arange(len(tasks))
    if across_tasks:
        unique = rng.permutation(np.unique(tasks))
        k = min(folds, len(unique))
        if k < 2:
            return []
        held = [np.flatnonzero(np.isin(tasks, unique[i::k])) for i in range(k)]
        return [Fold(train=np.setdiff1d(everyone, h), test=h) for h in held]
    _, inverse, counts = np.unique(tasks, return_inverse=True, return_counts=True)
    eligible = np.flatnonzero(counts[inverse] >= 2)
    k = min(folds, len(eligible))
    if k < 2:
        return []
    inner = split_episodes(tasks[eligible], 0.5, k, seed)
    return [Fold(train=np.setdiff1d(everyone, eligible[f.test]), test=eligible[f.test]) for f in inner]


def leave_one_task_out(episode_tasks: np.ndarray) -> list[Fold]:
    """One fold per task: train on every other task's episodes, test on this task's (cross-task probes)."""
    tasks = np.asarray(episode_tasks)
    if len(np.unique(tasks)) < 2:
        raise ValueError("leave-one-task-out needs episodes of at least 2 tasks")
    return [
        Fold(train=np.flatnonzero(tasks != task), test=np.flatnonzero(tasks == task))
        for task in np.unique(tasks)
    ]


def make_folds(episode_tasks: np.ndarray, cfg: SplitConfig, seed: int) -> list[Fold]:
    """The folds ``cfg`` asks for: :func:`split_episodes` or, with ``--split leave-one-task-out``,
    :func:`leave_one_task_out` (a one-line error when the episodes come from one task only)."""
    if cfg.by == "leave-one-task-out":
        if len(np.unique(episode_tasks)) < 2:
            from vlaprobe.errors import VlaprobeError

            raise VlaprobeError(
                "--split leave-one-task-out needs episodes of at least 2 tasks, the store has 1; collect more "
                "tasks (--tasks) or use the default --split episode"
            )
        return leave_one_task_out(episode_tasks)
    return split_episodes(episode_tasks, cfg.test_fraction, cfg.folds, seed)


def rows_of(episode: np.ndarray, episodes: np.ndarray) -> np.ndarray:
    """Row indices (sorted) of the steps that belong to the given episode positions."""
    return np.flatnonzero(np.isin(episode, episodes))


def check_no_leak(episode: np.ndarray, train_rows: np.ndarray, test_rows: np.ndarray) -> None:
    """Raise AssertionError if any step of a test episode is among the training rows.

    Checked on the rows actually handed to the trainer, so it guards the code path, not the intent.
    """
    train_eps = np.unique(episode[train_rows])
    test_eps = np.unique(episode[test_rows])
    shared = np.intersect1d(train_eps, test_eps)
    if len(shared) or len(np.intersect1d(train_rows, test_rows)):
        raise AssertionError(f"train/test leak: episodes {shared.tolist()[:10]} have steps on both sides")


UNDEFINED = "undefined"
"""How the reason of an atom dropped for being undefined (no row defines it) begins."""


@dataclass(frozen=True)
class LabelFilter:
    """Which atoms of a head are probed and why the others are not."""

    kept: np.ndarray
    """Column indices of the kept atoms."""
    dropped: list[dict]
    """One entry per dropped atom: {"atom", "train_frequency", "reason"}."""


def filter_labels(
    train_labels: list[np.ndarray] | np.ndarray,
    names: list[str],
    min_frequency: float,
    max_frequency: float,
    defined: list[np.ndarray] | np.ndarray | None = None,
    test_defined: np.ndarray | None = None,
) -> LabelFilter:
    """Drop atoms whose frequency in the training split is below ``min_frequency`` or above ``max_frequency``.

    Given several training splits (k-fold), an atom is dropped when any split would drop it, so all folds
    probe the same atoms; the recorded frequency is the offending one. ``defined`` (parallel to
    ``train_labels``, bool like each) counts a frequency over the rows that define the atom, and drops an atom
    no row of a split defines (an object absent from every training task); ``test_defined`` (held-out rows,
    atoms) drops an atom no held-out row defines: neither can be fit or scored.
    """
    splits = [train_labels] if isinstance(train_labels, np.ndarray) else list(train_labels)
    masks = (
        [None] * len(splits)
        if defined is None
        else ([defined] if isinstance(defined, np.ndarray) else list(defined))
    )
    freqs = np.stack([defined_frequency(y, m) for y, m in zip(splits, masks, strict=True)])  # (splits, atoms)
    undefined = np.isnan(freqs).any(axis=0)
    unscored = (
        np.zeros(len(names), bool)
        if test_defined is None
        else ~np.any(np.asarray(test_defined, bool), axis=0)
    )
    # (a split that does not define an atom drops it below, whatever its placeholder frequency)
    known = np.where(np.isnan(freqs), 0.5, freqs)
    low, high = known.min(axis=0), known.max(axis=0)
    kept, dropped = [], []
    for j, name in enumerate(names):
        if undefined[j] or unscored[j]:
            where = "training split" if undefined[j] else "held-out step"
            dropped.append({"atom": name, "train_frequency": 0.0, "reason": f"{UNDEFINED} in every {where}"})
        elif low[j] < min_frequency:
            dropped.append(
                {
                    "atom": name,
                    "train_frequency": float(low[j]),
                    "reason": f"train frequency {low[j]:.2%} < {min_frequency * 100:g}%",
                }
            )
        elif high[j] > max_frequency:
            dropped.append(
                {
                    "atom": name,
                    "train_frequency": float(high[j]),
                    "reason": f"train frequency {high[j]:.2%} > {max_frequency * 100:g}%",
                }
            )
        else:
            kept.append(j)
    return LabelFilter(kept=np.array(kept, np.int64), dropped=dropped)


def defined_frequency(labels: np.ndarray, defined: np.ndarray | None) -> np.ndarray:
    """(atoms,) share of true rows among the rows defining each atom (all rows without ``defined``); NaN where
    no row defines it."""
    if defined is None:
        return labels.mean(axis=0)
    n = defined.sum(axis=0)
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.where(n > 0, (labels & defined).sum(axis=0) / n, np.nan)
