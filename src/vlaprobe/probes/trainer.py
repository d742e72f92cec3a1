"""Per-layer multi-label linear probes, fit to convergence: standardised features, L2 strength by cross-validation.

All layers' probes are slices of one weight tensor and every (layer, atom) is an independent L2-regularised
logistic regression, solved together by the batched L-BFGS of :mod:`vlaprobe.probes.lbfgs` (one ``baddbmm``
for every logit, one ``bmm`` for every weight gradient) until each one's gradient is below ``tol``:

1. the training rows are copied once into one float32 (layers, rows, hidden) tensor, standardised with
   their own mean and standard deviation per layer and feature (saved with the probes, applied at readout);
2. the inverse L2 strength C is chosen per layer and head by episode-grouped cross-validation on the
   training rows (:mod:`vlaprobe.probes.regularization`): per fold, its atoms are the columns of one fit on
   its own rows, warm-started along the C grid;
3. the probes are fit on all training rows with their layer's and head's C, the searched atoms starting
   from the folds' mean solution at that C.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch

from vlaprobe.configs.train import ProbeConfig
from vlaprobe.devices import resolve_device
from vlaprobe.probes.apply import apply_probes_to_rows
from vlaprobe.probes.lbfgs import Convergence, cold_bias, fit_logistic, l2_of_c
from vlaprobe.probes.regularization import ColumnGroups, CrossValidation, choose_c


@dataclass
class LinearProbes:
    """Per-layer linear probes: ``logit = ((x - mean) / std) @ weight[layer] + bias[layer]``, every tensor on the
    CPU whatever device fit them."""

    weight: torch.Tensor
    """(layers, hidden, atoms) float32."""
    bias: torch.Tensor
    """(layers, atoms) float32."""
    mean: torch.Tensor | None = None
    """(layers, hidden) training-split feature means when standardizing, else None."""
    std: torch.Tensor | None = None
    """(layers, hidden) training-split feature standard deviations when standardizing, else None."""
    c: np.ndarray | None = None
    """(layers, atoms) inverse L2 strength each probe was fit with (scikit-learn's C)."""
    convergence: Convergence | None = None
    """Where the solver stopped for each (layer, atom)."""
    cv: CrossValidation | None = None
    """The cross-validation that chose ``c`` (None when C was given)."""

    def columns(self, cols: np.ndarray | slice) -> LinearProbes:
        """The probes of some atoms only (same standardisation)."""
        conv = self.convergence
        return LinearProbes(
            self.weight[:, :, cols],
            self.bias[:, cols],
            self.mean,
            self.std,
            None if self.c is None else self.c[:, cols],
            None if conv is None else conv.columns(cols),
            self.cv,
        )

    def logits(self, hidden: torch.Tensor, rows: np.ndarray | None = None, chunk: int = 1024) -> torch.Tensor:
        """Logits (layers, rows, atoms), on the CPU, of ``rows`` (default all) of ``hidden`` (layers, steps, hidden)."""
        return apply_probes_to_rows(hidden, self.weight, self.bias, self.mean, self.std, rows, chunk)


def training_matrix(
    hidden: torch.Tensor, rows: np.ndarray, device: torch.device, standardize: bool, chunk: int = 512
) -> tuple[torch.Tensor, torch.Tensor | None, torch.Tensor | None]:
    """``hidden[:, rows]`` as one contiguous float32 tensor on ``device``, standardised if asked.

    Returns (matrix, mean, std); the statistics (float32, (layers, hidden)) are over exactly these rows.
    """
    index = torch.as_tensor(np.asarray(rows), dtype=torch.long)
    num_layers, _, hidden_size = hidden.shape
    out = torch.empty((num_layers, len(index), hidden_size), dtype=torch.float32, device=device)
    for start in range(0, len(index), chunk):
        part = index[start : start + chunk]
        out[:, start : start + len(part)].copy_(hidden.index_select(1, part.to(hidden.device)))
    if not standardize:
        return out, None, None
    mean = out.double().mean(1)
    std = out.double().std(1, unbiased=False).clamp_min(1e-6)  # a constant feature: no 0/0
    mean, std = mean.float(), std.float()
    for start in range(0, len(index), chunk):
        view = out[:, start : start + chunk]
        view.sub_(mean[:, None]).div_(std[:, None])
    return out, mean, std


def fit_probes(
    hidden: torch.Tensor,
    targets: np.ndarray,
    rows: np.ndarray,
    cfg: ProbeConfig,
    seed: int,
    groups: ColumnGroups | None = None,
    c: float | np.ndarray | None = None,
    *,
    penalized: torch.Tensor | None = None,
    init: tuple[torch.Tensor, torch.Tensor] | None = None,
    defined: np.ndarray | None = None,
    warm_start: bool = True,
) -> LinearProbes:
    """Fit one multi-label probe per layer on ``rows`` of ``hidden`` (layers, steps, hidden).

    ``targets`` is bool/float (steps, atoms) over all steps; only ``rows`` are read. C is ``c`` when given
    (one value, or one per (layer, atom)), the single value of ``cfg.c_grid``, or chosen per layer and column
    group by cross-validation over the training episodes (needs ``groups``). Class balancing (``cfg.balance``)
    weights positives by the training negative/positive ratio. ``penalized`` and ``init``: as
    :func:`~vlaprobe.probes.lbfgs.fit_logistic`'s; without ``init``, a searched C's final fit starts from the
    search's solutions at that C (``warm_start``, see :func:`~vlaprobe.probes.regularization.choose_c`).
    ``defined`` (steps, atoms) bool like ``targets``, when given: an undefined entry (an atom over an object
    absent from the row's task) is left out of its atom's fit, C search and class balance (weight 0; the L2
    strength counts the defined rows).
    """
    device = resolve_device(cfg.device)
    rows = np.sort(np.asarray(rows))
    if len(rows) == 0:
        raise ValueError("no training rows")
    x, mean, std = training_matrix(hidden, rows, device, cfg.standardize)
    y = torch.as_tensor(np.asarray(targets)[rows], dtype=torch.float32, device=device)
    d = (
        None
        if defined is None
        else torch.as_tensor(np.asarray(defined)[rows], dtype=torch.float32, device=device)
    )
    num_layers = x.shape[0]
    n = x.shape[1] if d is None else d.sum(0).cpu().numpy()
    weight = d
    if cfg.balance:
        freq = y.mean(0) if d is None else (y * d).sum(0) / d.sum(0).clamp_min(1.0)
        freq = freq.clamp(1e-4, 1 - 1e-4)
        weight = 1 + ((1 - freq) / freq - 1) * y
        weight = weight if d is None else weight * d
    cv = None
    if c is not None or len(cfg.c_grid) == 1:
        given = c if c is not None else cfg.c_grid[0]
        per_column = np.array(np.broadcast_to(given, (num_layers, y.shape[1])), dtype=np.float64)
    elif groups is None:
        raise ValueError("choosing C by cross-validation needs the rows' episodes (groups=)")
    else:
        cv, per_column, searched = choose_c(x, y, rows, groups, cfg, seed, d, warm_start=warm_start)
        if init is None and searched is not None:
            init = _final_start(searched, groups.scored, y, weight)
    l2 = torch.as_tensor(l2_of_c(per_column, n), dtype=torch.float32)
    w, b, conv = fit_logistic(
        x,
        y,
        l2,
        weight=weight,
        tol=cfg.tol,
        max_iter=cfg.max_iter,
        history=cfg.history,
        memory_mb=cfg.memory_mb,
        init=init,
        penalized=penalized,
    )
    if mean is not None and std is not None:  # on the CPU, as fit_logistic returns the weights
        mean, std = mean.cpu(), std.cpu()
    return LinearProbes(weight=w, bias=b, mean=mean, std=std, c=per_column, convergence=conv, cv=cv)


def _final_start(
    searched: tuple[torch.Tensor, torch.Tensor],
    scored: np.ndarray,
    y: torch.Tensor,
    weight: torch.Tensor | None,
) -> tuple[torch.Tensor, torch.Tensor]:
    """The final fit's start: the search's (mean fold) solutions at the chosen C for the ``scored`` columns,
    the cold start (w = 0, b = the log-odds) for the others (e.g. shuffled-label copies, not searched)."""
    num_layers, hidden, _ = searched[0].shape
    cols = torch.as_tensor(np.flatnonzero(scored))
    w = torch.zeros((num_layers, hidden, y.shape[1]))
    b = cold_bias(y, weight).cpu().expand(num_layers, -1).clone()
    w[:, :, cols], b[:, cols] = searched
    return w, b
