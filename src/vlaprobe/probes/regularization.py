"""The L2 strength of the probes, chosen by cross-validation over whole training episodes.

Per layer and head, one inverse strength C from a log-spaced grid (``ProbeConfig.c_grid``, default 1e-4 to
1e2), shared by the head's atoms. Every C is scored by the metric the report selects layers by: the held-out
**balanced accuracy** at the probes' threshold (:func:`~vlaprobe.probes.metrics.metrics_from_counts`),
averaged over the head's scored atoms and the folds. The chosen C is the strongest penalty (smallest C)
whose score is within ``ProbeConfig.c_tolerance`` of the grid's best score: balanced accuracy is flat where
the predictions stop changing (all majority at strong penalties, a plateau at weak ones), and among C's the
folds cannot tell apart the smaller one is the simpler probe. A choice at either end of the grid means the
optimum may lie outside it: :meth:`CrossValidation.edge_of` flags it and ``vlaprobe train`` warns.

The folds divide the *training* episodes and are shaped like the split that scores the probes
(:func:`~vlaprobe.probes.split.search_folds`): with the default within-task split only episodes of tasks with
at least 2 training episodes are held out, so every held-out episode's task is trained on, as in the test
split; with ``--split leave-one-task-out`` whole tasks are held out. The test episodes never influence C.
Where nothing can be held out (one training episode per task) C is ``ProbeConfig.c_without_cv`` and
``vlaprobe train`` warns. Per C, every (fold, atom) is one column of a single batched fit
(:func:`~vlaprobe.probes.lbfgs.fit_logistic`), its fold's held-out rows weighted 0; the grid runs from the
strongest penalty to the weakest, each fit starting from the previous one's solution (a warm start: the
same minimiser, fewer iterations). The features are those of the final fit (standardised with the whole
training split's statistics, which use no label). The held-out log-loss is recorded too (``loss``).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import torch
import torch.nn.functional as F

from vlaprobe.configs.train import ProbeConfig
from vlaprobe.probes.lbfgs import fit_logistic, l2_of_c
from vlaprobe.probes.metrics import confusion_by_group, metrics_from_counts
from vlaprobe.probes.split import search_folds


@dataclass(frozen=True)
class ColumnGroups:
    """Which target columns share a C, and the episodes that group the rows for cross-validation."""

    episode: np.ndarray
    """int (steps,): episode position of every row of the data."""
    episode_tasks: np.ndarray
    """int (episodes,): task of each episode (the folds are stratified by it)."""
    group: np.ndarray
    """int (columns,): columns with the same id share one C per layer (e.g. the atoms of one head)."""
    scored: np.ndarray
    """bool (columns,): columns whose held-out score chooses their group's C (the real atoms, not the
    shuffled-label copies, which take the C of their group)."""
    across_tasks: bool = False
    """The probes are tested on tasks they were not trained on (``--split leave-one-task-out``): the search's
    folds hold out whole tasks too."""


@dataclass
class CrossValidation:
    """What the cross-validation measured and chose."""

    grid: list[float]
    """The C values, ascending (strongest penalty first)."""
    folds: int
    """Folds actually used (fewer than asked when there are fewer training episodes)."""
    loss: np.ndarray
    """(layers, groups, grid): mean held-out log-loss over the group's scored atoms and the folds."""
    chosen: np.ndarray
    """(layers, groups): the chosen C."""
    ids: np.ndarray
    """The group id of each entry of the groups axis."""
    score: np.ndarray | None = None
    """(layers, groups, grid): mean held-out balanced accuracy over the group's scored atoms and the folds
    (the selection criterion)."""
    tolerance: float = 0.0
    """The chosen C is the smallest whose score is at least the best score minus this."""
    fold_test: tuple[np.ndarray, ...] = ()
    """Per fold, the held-out training episodes (positions in the data's episode list)."""

    def _index(self, group: int) -> int:
        return int(np.searchsorted(self.ids, group))

    def of_group(self, group: int) -> tuple[np.ndarray, np.ndarray]:
        """(loss (layers, grid), chosen C (layers,)) of one column group."""
        i = self._index(group)
        return self.loss[:, i], self.chosen[:, i]

    def score_of(self, group: int) -> np.ndarray | None:
        """(layers, grid) mean held-out balanced accuracy of one column group."""
        return None if self.score is None else self.score[:, self._index(group)]

    def edge_of(self, group: int) -> np.ndarray:
        """bool (layers,): the group's chosen C is the grid's smallest or largest (never with one C)."""
        chosen = self.chosen[:, self._index(group)]
        if len(self.grid) < 2:
            return np.zeros(len(chosen), bool)
        return (chosen == self.grid[0]) | (chosen == self.grid[-1])


def select_c(score: np.ndarray, grid: list[float], tolerance: float) -> np.ndarray:
    """Per entry of ``score`` (..., grid), the smallest C of ascending ``grid`` scoring at least the best
    score minus ``tolerance`` (the largest C where no C has a defined score)."""
    filled = np.where(np.isnan(score), -np.inf, score)
    best = filled.max(-1, keepdims=True)
    good = filled >= best - tolerance
    index = np.where(np.isfinite(best[..., 0]), np.argmax(good, -1), len(grid) - 1)
    return np.asarray(grid)[index]


def _held_out(
    x: torch.Tensor,
    truth: np.ndarray,
    w: torch.Tensor,
    b: torch.Tensor,
    fold_rows: list[np.ndarray],
    threshold_logit: float,
    chunk: int = 2,
    defined: np.ndarray | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """(layers, folds, scored) held-out log-loss and balanced accuracy of each fold's columns on its rows.

    Fold f's probes are the columns ``f * scored ... (f + 1) * scored`` of ``w``, ``b``; its held-out rows are
    ``fold_rows[f]``; ``truth`` is bool (rows, scored). ``defined`` (rows, scored) bool leaves the undefined
    entries out of both (NaN where a fold holds out no defined row of an atom).
    """
    num_layers, scored = x.shape[0], truth.shape[1]
    loss = np.empty((num_layers, len(fold_rows), scored))
    balanced = np.empty_like(loss)
    y = torch.as_tensor(truth, dtype=torch.float32, device=x.device)
    d = None if defined is None else torch.as_tensor(defined, dtype=torch.float32, device=x.device)
    for start in range(0, num_layers, chunk):
        part = slice(start, min(num_layers, start + chunk))
        for f, rows in enumerate(fold_rows):
            cols = slice(f * scored, (f + 1) * scored)
            index = torch.as_tensor(rows, dtype=torch.long, device=x.device)
            z = torch.baddbmm(
                b[part, None, cols].to(x.device),
                x[part].index_select(1, index),
                w[part, :, cols].to(x.device),
            )
            entry = F.softplus(z) - y[index] * z
            if d is None:
                loss[part, f] = entry.mean(1).cpu().numpy()
            else:
                n = d[index].sum(0)
                mean = (entry * d[index]).sum(1) / n.clamp_min(1.0)
                loss[part, f] = torch.where(n > 0, mean, torch.nan).cpu().numpy()
            held = None if defined is None else defined[rows]
            counts = confusion_by_group(
                (z > threshold_logit).cpu(), truth[rows], np.zeros(len(rows)), 1, held
            )
            balanced[part, f] = metrics_from_counts(counts[0])["balanced_accuracy"]
    return loss, balanced


def _group_mean(x: np.ndarray, scored_group: np.ndarray, ids: np.ndarray) -> np.ndarray:
    """(layers, grid, folds, scored) -> (layers, groups, grid): mean over the folds and each group's atoms,
    leaving out undefined (NaN) entries."""
    out = np.full((x.shape[0], len(ids), x.shape[1]), np.nan)
    for i, g in enumerate(ids):
        part = x[..., scored_group == g].reshape(x.shape[0], x.shape[1], -1)
        defined = ~np.isnan(part)
        with np.errstate(invalid="ignore"):
            out[:, i] = np.where(defined.any(-1), np.nansum(part, -1) / defined.sum(-1), np.nan)
    return out


def choose_c(
    x: torch.Tensor,
    y: torch.Tensor,
    rows: np.ndarray,
    groups: ColumnGroups,
    cfg: ProbeConfig,
    seed: int,
    defined: torch.Tensor | None = None,
) -> tuple[CrossValidation | None, np.ndarray]:
    """C per (layer, column) for training rows ``rows`` (features ``x`` (layers, rows, hidden), targets ``y``).

    ``defined`` (rows, columns) 0/1, when given: the undefined entries are left out of every fit (weight 0,
    the L2 strength counting the defined rows) and of every held-out score. Returns the cross-validation
    record (None when no fold can be held out: then ``cfg.c_without_cv``) and (layers, columns) C values.
    """
    grid = sorted(float(c) for c in cfg.c_grid)
    num_layers = x.shape[0]
    ids = np.unique(groups.group)
    episodes = np.unique(groups.episode[rows])
    folds = search_folds(groups.episode_tasks[episodes], cfg.cv_folds, seed, groups.across_tasks)
    if not folds:
        return None, np.full((num_layers, y.shape[1]), cfg.c_without_cv)
    row_episode = np.searchsorted(episodes, groups.episode[rows])
    scored = np.flatnonzero(groups.scored)
    ys = y[:, scored]
    in_fold = [np.isin(row_episode, f.train) for f in folds]
    masks = [torch.as_tensor(m, dtype=torch.float32, device=x.device) for m in in_fold]
    ds = None if defined is None else defined[:, scored].to(x.device, torch.float32)
    fits = [m[:, None].expand(-1, len(scored)) if ds is None else m[:, None] * ds for m in masks]
    weight = torch.cat(fits, 1)  # (rows, folds * scored)
    counts = [f.sum(0).cpu().numpy() for f in fits]  # per fold, the rows each column is fit on
    targets = ys.repeat(1, len(folds))
    truth = ys.cpu().numpy() > 0.5
    held_rows = [np.flatnonzero(~m) for m in in_fold]
    held_defined = None if ds is None else ds.cpu().numpy() > 0.5
    threshold_logit = math.log(cfg.threshold / (1 - cfg.threshold))
    losses, scores, start = [], [], None
    for c in grid:  # ascending: each C starts from the solution of the stronger penalty before it
        l2 = np.concatenate([l2_of_c(c, n) for n in counts])
        l2_t = torch.as_tensor(l2, dtype=torch.float32)[None].expand(num_layers, -1).contiguous()
        w, b, _ = fit_logistic(
            x,
            targets,
            l2_t,
            weight=weight,
            tol=cfg.tol,
            max_iter=cfg.max_iter,
            history=cfg.history,
            memory_mb=cfg.memory_mb,
            init=start,
        )
        start = (w, b)
        loss, balanced = _held_out(x, truth, w, b, held_rows, threshold_logit, defined=held_defined)
        losses.append(loss)
        scores.append(balanced)
    scored_group = groups.group[scored]
    loss = _group_mean(np.stack(losses, 1), scored_group, ids)  # (layers, groups, grid)
    score = _group_mean(np.stack(scores, 1), scored_group, ids)
    chosen = select_c(score, grid, cfg.c_tolerance)
    per_column = chosen[:, np.searchsorted(ids, groups.group)]
    cv = CrossValidation(
        grid, len(folds), loss, chosen, ids, score, cfg.c_tolerance, tuple(episodes[f.test] for f in folds)
    )
    return cv, per_column
