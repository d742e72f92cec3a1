"""The L2 strength of the probes, chosen by cross-validation over whole training episodes.

Per layer and head, one inverse strength C from a small grid (``ProbeConfig.c_grid``), shared by the head's
atoms: the one with the lowest held-out log-loss, averaged over the head's atoms and the folds. The folds
divide the *training* episodes (stratified by task, as the train/test split), so the test episodes never
influence C. Per C, every (fold, atom) is one column of a single batched fit
(:func:`~vlaprobe.probes.lbfgs.fit_logistic`), its fold's held-out rows weighted 0; the grid runs from the
strongest penalty to the weakest, each fit starting from the previous one's solution (a warm start: the
same minimiser, fewer iterations). The features are those of the final fit (standardised with the whole
training split's statistics, which use no label).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch
import torch.nn.functional as F

from vlaprobe.configs.train import ProbeConfig
from vlaprobe.probes.lbfgs import fit_logistic, l2_of_c
from vlaprobe.probes.split import split_episodes


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
    """bool (columns,): columns whose held-out loss chooses their group's C (the real atoms, not the
    shuffled-label copies, which take the C of their group)."""


@dataclass
class CrossValidation:
    """What the cross-validation measured and chose."""

    grid: list[float]
    folds: int
    """Folds actually used (fewer than asked when there are fewer training episodes)."""
    loss: np.ndarray
    """(layers, groups, grid): mean held-out log-loss over the group's scored atoms and the folds."""
    chosen: np.ndarray
    """(layers, groups): the chosen C."""
    ids: np.ndarray
    """The group id of each entry of the groups axis."""

    def of_group(self, group: int) -> tuple[np.ndarray, np.ndarray]:
        """(loss (layers, grid), chosen C (layers,)) of one column group."""
        i = int(np.searchsorted(self.ids, group))
        return self.loss[:, i], self.chosen[:, i]


def _held_out_loss(
    x: torch.Tensor, y: torch.Tensor, w: torch.Tensor, b: torch.Tensor, held: torch.Tensor, chunk: int = 2
) -> np.ndarray:
    """(layers, columns) mean log-loss over each column's held-out rows (``held`` (rows, columns) float 0/1)."""
    out = np.empty(b.shape)
    count = held.sum(0).clamp_min(1.0)
    for start in range(0, x.shape[0], chunk):
        part = slice(start, start + chunk)
        z = torch.baddbmm(b[part, None].to(x.device), x[part], w[part].to(x.device))
        loss = (F.softplus(z) - y * z) * held
        out[part] = (loss.sum(1) / count).cpu().numpy()
    return out


def choose_c(
    x: torch.Tensor, y: torch.Tensor, rows: np.ndarray, groups: ColumnGroups, cfg: ProbeConfig, seed: int
) -> tuple[CrossValidation | None, np.ndarray]:
    """C per (layer, column) for training rows ``rows`` (features ``x`` (layers, rows, hidden), targets ``y``).

    Returns the cross-validation record (None when fewer than 2 training episodes: then the grid's largest C)
    and (layers, columns) C values.
    """
    grid = sorted(float(c) for c in cfg.c_grid)
    num_layers = x.shape[0]
    ids = np.unique(groups.group)
    episodes = np.unique(groups.episode[rows])
    if len(episodes) < 2:
        return None, np.full((num_layers, y.shape[1]), grid[-1])
    k = min(cfg.cv_folds, len(episodes))
    folds = split_episodes(groups.episode_tasks[episodes], 0.5, k, seed)
    row_episode = np.searchsorted(episodes, groups.episode[rows])
    scored = np.flatnonzero(groups.scored)
    ys = y[:, scored]
    masks = [
        torch.as_tensor(np.isin(row_episode, f.train), dtype=torch.float32, device=x.device) for f in folds
    ]
    weight = torch.cat([m[:, None].expand(-1, len(scored)) for m in masks], 1)  # (rows, folds * scored)
    targets = ys.repeat(1, len(folds))
    held, start = [], None
    for c in grid:  # ascending: each C starts from the solution of the stronger penalty before it
        l2 = np.concatenate([np.full(len(scored), l2_of_c(c, float(m.sum()))) for m in masks])
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
        held.append(_held_out_loss(x, targets, w, b, 1.0 - weight))  # (layers, folds * scored)
    mean_held = np.stack(held, 1).reshape(num_layers, len(grid), len(folds), len(scored)).mean(2)
    scored_group = groups.group[scored]
    loss = np.stack([mean_held[:, :, scored_group == g].mean(2) for g in ids], 1)  # (layers, groups, grid)
    chosen = np.asarray(grid)[np.argmin(loss, axis=2)]  # first minimum: the smallest C, strongest penalty
    per_column = chosen[:, np.searchsorted(ids, groups.group)]
    return CrossValidation(grid, len(folds), loss, chosen, ids), per_column
