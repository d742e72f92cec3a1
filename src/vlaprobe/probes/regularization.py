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
``vlaprobe train`` warns. Per fold and C, the fold's atoms are the columns of one batched fit
(:func:`~vlaprobe.probes.lbfgs.fit_logistic`) on the fold's own training rows; the grid runs from the
strongest penalty to the weakest, each fit starting from the fold's solution at the C before it (a warm
start along the regularisation path, as scikit-learn's ``LogisticRegressionCV``: the same minimiser, fewer
iterations), and the final fit on all training rows starts from the mean of the folds' solutions at the
chosen C. With a union store's defined mask, each fold's fit weights its undefined (row, atom) entries 0 (the
L2 strength counting each atom's defined rows) and its held-out scores leave them out. The features are those
of the final fit (standardised with the whole training split's statistics, which use no label). The held-out
log-loss is recorded too (``loss``).
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
    held: np.ndarray,
    truth: np.ndarray,
    w: torch.Tensor,
    b: torch.Tensor,
    threshold_logit: float,
    chunk: int = 2,
    defined: np.ndarray | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """(layers, scored) held-out log-loss and balanced accuracy of one fold's probes ``w`` (layers, hidden,
    scored), ``b`` on its held-out rows ``held`` of ``x`` (layers, rows, hidden); ``truth`` bool (held, scored).
    ``defined`` bool like ``truth``, when given, leaves the undefined entries out of both (NaN where the fold
    holds out no defined row of an atom)."""
    num_layers, scored = x.shape[0], truth.shape[1]
    loss = np.empty((num_layers, scored))
    balanced = np.empty_like(loss)
    y = torch.as_tensor(truth, dtype=torch.float32, device=x.device)
    d = None if defined is None else torch.as_tensor(defined, dtype=torch.float32, device=x.device)
    index = torch.as_tensor(held, dtype=torch.long, device=x.device)
    for start in range(0, num_layers, chunk):
        part = slice(start, min(num_layers, start + chunk))
        z = torch.baddbmm(b[part, None].to(x.device), x[part].index_select(1, index), w[part].to(x.device))
        entry = F.softplus(z) - y * z
        if d is None:
            loss[part] = entry.mean(1).cpu().numpy()
        else:
            n = d.sum(0)
            mean = (entry * d).sum(1) / n.clamp_min(1.0)
            loss[part] = torch.where(n > 0, mean, torch.nan).cpu().numpy()
        counts = confusion_by_group((z > threshold_logit).cpu(), truth, np.zeros(len(truth)), 1, defined)
        balanced[part] = metrics_from_counts(counts[0])["balanced_accuracy"]
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


Start = tuple[torch.Tensor, torch.Tensor]
"""A solver start: weights (layers, hidden, columns) and biases (layers, columns), as ``fit_logistic``'s ``init``."""


def choose_c(
    x: torch.Tensor,
    y: torch.Tensor,
    rows: np.ndarray,
    groups: ColumnGroups,
    cfg: ProbeConfig,
    seed: int,
    defined: torch.Tensor | None = None,
    *,
    warm_start: bool = True,
) -> tuple[CrossValidation | None, np.ndarray, Start | None]:
    """C per (layer, column) for training rows ``rows`` (features ``x`` (layers, rows, hidden), targets ``y``).

    Returns the cross-validation record (None when no fold can be held out: then ``cfg.c_without_cv``),
    (layers, columns) C values and, with ``warm_start``, a start for the final fit of the scored columns: the
    mean over the folds of their probes at the chosen C (else None). Each fold is fit on its own training rows;
    with ``warm_start`` each C of the ascending grid starts from the fold's solution at the C before it, else
    from the cold start (the same minimisers: ``warm_start=False`` is there to check and time that).
    ``defined`` (rows, columns) 0/1, when given: the undefined entries are left out of every fit (weight 0,
    the L2 strength counting each column's defined rows), of every held-out score and of the start's mean
    (a fold that defines none of a column's fit rows does not count).
    """
    grid = sorted(float(c) for c in cfg.c_grid)
    num_layers = x.shape[0]
    ids = np.unique(groups.group)
    episodes = np.unique(groups.episode[rows])
    folds = search_folds(groups.episode_tasks[episodes], cfg.cv_folds, seed, groups.across_tasks)
    if not folds:
        return None, np.full((num_layers, y.shape[1]), cfg.c_without_cv), None
    row_episode = np.searchsorted(episodes, groups.episode[rows])
    scored = np.flatnonzero(groups.scored)
    ys = y[:, scored]
    ds = None if defined is None else defined[:, scored].to(x.device, torch.float32)
    truth = ys.cpu().numpy() > 0.5
    held_defined = None if ds is None else ds.cpu().numpy() > 0.5
    threshold_logit = math.log(cfg.threshold / (1 - cfg.threshold))
    losses = np.empty((num_layers, len(grid), len(folds), len(scored)))
    scores = np.empty_like(losses)
    size = (num_layers, x.shape[2], len(scored))
    path = [(torch.zeros(size), torch.zeros((num_layers, len(scored)))) for _ in grid] if warm_start else []
    # (per C, the folds' solutions summed: the final fit's start; with a mask, per column the folds summed)
    summed: torch.Tensor | int = len(folds) if ds is None else torch.zeros(len(scored))
    for f, fold in enumerate(folds):
        in_fold = np.isin(row_episode, fold.train)
        fit_rows = torch.as_tensor(np.flatnonzero(in_fold), dtype=torch.long, device=x.device)
        held = np.flatnonzero(~in_fold)
        xf, yf = x.index_select(1, fit_rows), ys.index_select(0, fit_rows)  # the fold's rows only
        df = None if ds is None else ds.index_select(0, fit_rows)  # its fit's weights: the defined entries
        n = np.full(len(scored), len(fit_rows)) if df is None else df.sum(0).cpu().numpy()
        has = None if df is None else torch.as_tensor(n > 0, dtype=torch.float32)
        held_d = None if held_defined is None else held_defined[held]
        start: Start | None = None
        for j, c in enumerate(grid):  # ascending: each C starts from the solution of the stronger penalty
            l2 = torch.as_tensor(l2_of_c(c, n), dtype=torch.float32)[None].expand(num_layers, -1).contiguous()
            w, b, _ = fit_logistic(
                xf,
                yf,
                l2,
                weight=df,
                tol=cfg.tol,
                max_iter=cfg.max_iter,
                history=cfg.history,
                memory_mb=cfg.memory_mb,
                init=start,
            )
            losses[:, j, f], scores[:, j, f] = _held_out(
                x, held, truth[held], w, b, threshold_logit, defined=held_d
            )
            if warm_start:
                start = (w, b)
                path[j][0].add_(w if has is None else w * has)
                path[j][1].add_(b if has is None else b * has)
        if has is not None and isinstance(summed, torch.Tensor):
            summed.add_(has)
        del xf, df
    scored_group = groups.group[scored]
    loss = _group_mean(losses, scored_group, ids)  # (layers, groups, grid)
    score = _group_mean(scores, scored_group, ids)
    chosen = select_c(score, grid, cfg.c_tolerance)
    per_column = chosen[:, np.searchsorted(ids, groups.group)]
    cv = CrossValidation(
        grid, len(folds), loss, chosen, ids, score, cfg.c_tolerance, tuple(episodes[f.test] for f in folds)
    )
    return cv, per_column, _start_at(path, np.searchsorted(grid, per_column[:, scored]), summed)


def _start_at(path: list[Start], at: np.ndarray, folds: torch.Tensor | int) -> Start | None:
    """The mean fold solution at grid index ``at`` (layers, scored) of every (layer, column), ``folds`` the
    number of folds summed (or per column); None without a path."""
    if not path:
        return None
    w, b = torch.zeros_like(path[0][0]), torch.zeros_like(path[0][1])
    for j, (wj, bj) in enumerate(path):
        pick = torch.as_tensor(at == j)
        w = torch.where(pick[:, None], wj, w)
        b = torch.where(pick, bj, b)
    if isinstance(folds, torch.Tensor):
        folds = folds.clamp_min(1.0)
    return w / folds, b / folds
