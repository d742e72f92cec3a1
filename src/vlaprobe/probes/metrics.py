"""Classification metrics per (layer, atom), their episode-bootstrap intervals, and averages per predicate.

Counts first: per test episode, layer and atom the confusion counts (tp, fp, fn, tn). A bootstrap resample
draws test episodes with replacement, so its counts are a weighted sum of the per-episode counts and
accuracy, balanced accuracy and F1 of a thousand resamples cost one small matmul. AUPRC needs the ranking
of scores: every column is sorted once and each resample only reweights the sorted rows.

A metric that is undefined (F1 or AUPRC with no positive step, a recall with no members of its class) is NaN
and left out of averages; :func:`summarize` reports how many atoms each average covers. A bootstrap resample
that lacks a class the full test set has (e.g. none of an atom's positive episodes was drawn) leaves the
atom's balanced accuracy and F1 undefined in that resample, as they would be on such a test set, instead of
scoring only the class that is left (which biased the intervals upward); each figure records in how many
resamples it was defined.
"""

from __future__ import annotations

import numpy as np
import torch
import torch.nn.functional as F

METRICS = ("accuracy", "balanced_accuracy", "f1", "auprc")
"""Every metric reported, in display order."""
COUNT_METRICS = ("accuracy", "balanced_accuracy", "f1")
"""Metrics computed from confusion counts."""


def confusion_by_group(
    pred: torch.Tensor, truth: np.ndarray, groups: np.ndarray, num_groups: int
) -> np.ndarray:
    """Confusion counts (groups, layers, atoms, 4 = tp, fp, fn, tn) of bool ``pred`` (layers, rows, atoms).

    ``truth`` is bool (rows, atoms); ``groups`` int (rows,) in [0, num_groups), e.g. the test episode.
    """
    pred = pred.bool()
    truth_t = torch.as_tensor(np.asarray(truth, bool))
    index = torch.as_tensor(np.asarray(groups), dtype=torch.long)
    atoms = pred.shape[2]

    def group_sum(x: torch.Tensor) -> torch.Tensor:  # (layers, rows, atoms) -> (groups, layers, atoms)
        out = torch.zeros((num_groups, x.shape[0], atoms), dtype=torch.float64)
        return out.index_add_(0, index, x.permute(1, 0, 2).double())

    tp = group_sum(pred & truth_t)
    predicted = group_sum(pred)
    positives = group_sum(truth_t[None])
    sizes = torch.bincount(index, minlength=num_groups).double()[:, None, None]
    fp, fn = predicted - tp, positives - tp
    tn = sizes - tp - fp - fn
    return torch.stack([tp, fp, fn, tn.expand_as(tp)], dim=-1).numpy()


def metrics_from_counts(counts: np.ndarray) -> dict[str, np.ndarray]:
    """accuracy, balanced accuracy (mean of the defined class recalls) and F1 (undefined without a positive
    step, whatever the false positives) from (..., 4) counts."""
    tp, fp, fn, tn = (counts[..., i] for i in range(4))
    with np.errstate(invalid="ignore", divide="ignore"):
        accuracy = (tp + tn) / (tp + fp + fn + tn)
        recalls = np.stack([tp / (tp + fn), tn / (tn + fp)])
        defined = ~np.isnan(recalls)
        balanced = np.where(defined.any(0), np.nansum(recalls, 0) / defined.sum(0), np.nan)
        f1 = np.where(tp + fn > 0, 2 * tp / (2 * tp + fp + fn), np.nan)
    return {"accuracy": accuracy, "balanced_accuracy": balanced, "f1": f1}


def _sorted_blocks(scores: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """Each column's descending order (stable) and, per sorted row, the last row of its block of tied scores."""
    n = scores.shape[0]
    sorted_scores, order = torch.sort(scores, dim=0, descending=True, stable=True)
    last = torch.ones_like(sorted_scores, dtype=torch.bool)
    last[:-1] = sorted_scores[1:] != sorted_scores[:-1]
    positions = torch.arange(n).unsqueeze(1).expand_as(last)
    block_end = torch.where(last, positions, torch.full_like(positions, n - 1))
    return order, torch.flip(torch.cummin(torch.flip(block_end, [0]), dim=0).values, [0])


def average_precision(scores: torch.Tensor, truth: torch.Tensor) -> torch.Tensor:
    """Average precision (area under the step-wise precision-recall curve) of each column.

    ``scores`` float (rows, columns), ``truth`` bool (rows, columns). Returns (columns,); NaN where a column
    has no positives.

    AP = sum over thresholds t of (recall(t) - recall(t_prev)) * precision(t), thresholds being the distinct
    scores: rows with equal scores enter together, so ties are neither rewarded nor punished by their order.
    Equivalently, every positive row contributes precision at the end of its block of tied scores.
    """
    scores = torch.as_tensor(scores, dtype=torch.float64)
    order, block_end = _sorted_blocks(scores)
    y = torch.as_tensor(truth).bool().gather(0, order).double()
    positions = torch.arange(scores.shape[0]).unsqueeze(1)
    precision = (torch.cumsum(y, 0) / (positions + 1).double()).gather(0, block_end)
    total = y.sum(0)
    return torch.where(total > 0, (y * precision).sum(0) / total, torch.nan)


def resampled_average_precision(
    scores: torch.Tensor,
    truth: np.ndarray,
    groups: np.ndarray,
    group_weights: np.ndarray,
    budget: int = 4_000_000,
) -> np.ndarray:
    """:func:`average_precision` of every column in every bootstrap resample of whole groups (episodes).

    ``scores`` (rows, columns) share one ``truth`` (rows,) bool (e.g. one atom read at every layer);
    ``groups`` (rows,) int, the group of each row; ``group_weights`` (resamples, groups) multiplicities.
    Returns (resamples, columns), NaN where a resample draws no positive row.

    A resample counts each row as often as its group is drawn, so the true positives and the rows seen above a
    threshold are, per group, counts among the rows above it times the group's multiplicity: a small matmul
    over the groups, evaluated at the positive rows only (the only ones that enter AP), instead of cumulative
    sums over every (resample, row, column). Counts and multiplicities are integers, exact in float32. Columns
    are taken in chunks of at most ``budget`` (rows x groups) and (rows x resamples) entries.
    """
    w = torch.as_tensor(group_weights, dtype=torch.float32)  # (R, G)
    truth_t = torch.as_tensor(np.asarray(truth, bool))
    group_t = torch.as_tensor(np.asarray(groups), dtype=torch.long)
    scores = torch.as_tensor(scores, dtype=torch.float64)
    num_groups, (rows, columns) = w.shape[1], scores.shape
    out = np.full((w.shape[0], columns), np.nan)
    npos = int(truth_t.sum())
    total = torch.bincount(group_t[truth_t], minlength=num_groups).float() @ w.T  # (R,) positives drawn
    if npos == 0:
        return out
    chunk = max(1, budget // max(1, rows * max(num_groups, w.shape[0])))
    for start in range(0, columns, chunk):
        order, block_end = _sorted_blocks(scores[:, start : start + chunk])  # (n, c)
        sorted_group, sorted_truth = group_t[order], truth_t[order]
        seen = F.one_hot(sorted_group, num_groups).float()  # (n, c, G)
        positive = (seen * sorted_truth[..., None]).cumsum(0)
        seen = seen.cumsum(0)
        # The positive rows' sorted positions, (npos, c), and the end of each one's block of ties.
        at = torch.argsort((~sorted_truth).to(torch.int8), dim=0, stable=True)[:npos]
        end = block_end.gather(0, at)[..., None].expand(-1, -1, num_groups)
        tp, drawn = positive.gather(0, end) @ w.T, seen.gather(0, end) @ w.T  # (npos, c, R)
        precision = tp / drawn.clamp_min(1e-12)
        own = w.T[sorted_group.gather(0, at)]  # (npos, c, R): each positive row's multiplicity
        ap = (own * precision).sum(0) / total.clamp_min(1e-12)  # (c, R)
        out[:, start : start + chunk] = torch.where(total > 0, ap, torch.nan).T.double().numpy()
    return out


def bootstrap_weights(num_groups: int, resamples: int, seed: int) -> np.ndarray:
    """(resamples, groups) multiplicities of groups drawn with replacement, as many as there are groups."""
    rng = np.random.default_rng(seed)
    return rng.multinomial(num_groups, np.full(num_groups, 1.0 / num_groups), size=resamples).astype(
        np.float64
    )


def atom_metrics(
    logits: torch.Tensor,
    truth: np.ndarray,
    groups: np.ndarray,
    num_groups: int,
    threshold_logit: float,
    weights: np.ndarray,
    auprc_resamples: int,
) -> tuple[dict[str, np.ndarray], dict[str, np.ndarray]]:
    """Point values (layers, atoms) and bootstrap resamples (resamples, layers, atoms) of every metric.

    Predictions are ``logits > threshold_logit``; AUPRC ranks the logits. AUPRC resamples are the first
    ``auprc_resamples`` rows of ``weights`` (an empty array when 0).
    """
    counts = confusion_by_group(logits > threshold_logit, truth, groups, num_groups)
    total = counts.sum(0)
    point = metrics_from_counts(total)
    resampled_counts = np.einsum("rg,glac->rlac", weights, counts)
    resampled = metrics_from_counts(resampled_counts)
    # A class present in the test set but absent from a resample: the class-balanced metrics are undefined.
    positives, negatives = total[..., 0] + total[..., 2], total[..., 1] + total[..., 3]
    r_pos = resampled_counts[..., 0] + resampled_counts[..., 2]
    r_neg = resampled_counts[..., 1] + resampled_counts[..., 3]
    missing = ((positives > 0) & (r_pos == 0)) | ((negatives > 0) & (r_neg == 0))
    resampled["balanced_accuracy"] = np.where(missing, np.nan, resampled["balanced_accuracy"])
    layers, _, atoms = logits.shape
    columns = logits.permute(1, 0, 2).reshape(logits.shape[1], layers * atoms)
    truth_cols = torch.as_tensor(np.asarray(truth, bool)).repeat(1, layers)
    point["auprc"] = average_precision(columns, truth_cols).reshape(layers, atoms).numpy()
    group_weights = weights[:auprc_resamples]
    resampled["auprc"] = np.empty((len(group_weights), layers, atoms))
    if len(group_weights):
        for a in range(atoms):  # one atom at every layer: the same positives
            resampled["auprc"][:, :, a] = resampled_average_precision(
                logits[:, :, a].T, np.asarray(truth)[:, a], groups, group_weights
            )
    return point, resampled


def _interval(resampled: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """2.5th and 97.5th percentiles over axis 0, NaN where fewer than 2 resamples are defined."""
    if resampled.shape[0] < 2:
        nan = np.full(resampled.shape[1:], np.nan)
        return nan, nan
    ok = (~np.isnan(resampled)).sum(0) >= 2
    low, high = nan_percentiles(resampled, (2.5, 97.5))
    return np.where(ok, low, np.nan), np.where(ok, high, np.nan)


def nan_percentiles(x: np.ndarray, qs: tuple[float, ...]) -> list[np.ndarray]:
    """``np.nanpercentile(x, q, axis=0)`` for each q (its default linear method, the same numbers), NaN
    where a column has no defined value. One sort of the whole array instead of numpy's per-column loop
    for arrays with NaNs (seconds on the layers x atoms of a probe evaluation)."""
    ordered = np.sort(x, axis=0)  # NaNs sort last
    n = (~np.isnan(x)).sum(0)
    out = []
    for q in qs:
        virtual = (n - 1) * (q / 100)
        below = np.clip(np.floor(virtual), 0, np.maximum(n - 1, 0)).astype(np.int64)
        above = np.minimum(below + 1, np.maximum(n - 1, 0))
        t = virtual - below
        a = np.take_along_axis(ordered, below[None], 0)[0]
        b = np.take_along_axis(ordered, above[None], 0)[0]
        with np.errstate(invalid="ignore"):
            diff = b - a
            value = np.where(t >= 0.5, b - diff * (1 - t), a + diff * t)  # numpy's _lerp, the same rounding
        out.append(np.where(n > 0, value, np.nan))
    return out


def _nanmean(x: np.ndarray, axis: int) -> np.ndarray:
    defined = ~np.isnan(x)
    with np.errstate(invalid="ignore"):
        return np.where(defined.any(axis), np.nansum(x, axis) / defined.sum(axis), np.nan)


def _complete(point: np.ndarray, resampled: np.ndarray, axis_atoms: list[np.ndarray]) -> np.ndarray:
    """Per group of atom columns: resamples in which every atom defined at the point was defined too."""
    missing = np.isnan(resampled) & ~np.isnan(point)[None]  # (resamples, layers, atoms)
    return np.stack([(~missing[:, :, g].any(2)).sum(0) for g in axis_atoms], 1)


def fixed_set(point: np.ndarray, resampled: np.ndarray) -> np.ndarray:
    """Resampled per-atom values for averages over a fixed set of atoms: those defined at the point.

    An atom undefined at the point (on the full test set) is left out of every resample; an atom defined at
    the point but not in a resample (the resample drew none of its positive, or negative, episodes) enters
    that resample's average with its full-test-set value. Leaving it out instead would average a different
    set of atoms in each resample (mostly without the rare ones), which moved the interval away from the point.
    """
    defined_at_point = ~np.isnan(point)[None]
    filled = np.where(np.isnan(resampled) & defined_at_point, point[None], resampled)
    return np.where(defined_at_point, filled, np.nan)


def summarize(
    point: np.ndarray, resampled: np.ndarray, groups: list[np.ndarray]
) -> dict[str, dict[str, np.ndarray]]:
    """Per atom, per predicate (mean over ``groups`` of atom columns) and per layer (mean over all atoms).

    ``point`` is (layers, atoms), ``resampled`` (resamples, layers, atoms). Each level gets its value and a
    95% percentile interval computed from the same resamples (so intervals of averages are correct,
    not averages of intervals; averages over the fixed set of :func:`fixed_set`); ``count`` says how many atoms were defined in each average and ``defined`` in
    how many resamples the figure was defined over all of its atoms (an atom: in which it was defined).
    """
    out: dict[str, dict[str, np.ndarray]] = {}
    low, high = _interval(resampled)
    fixed = fixed_set(point, resampled)
    out["atom"] = {"value": point, "low": low, "high": high, "defined": (~np.isnan(resampled)).sum(0)}
    pred_point = np.stack([_nanmean(point[:, g], 1) for g in groups], 1)
    pred_res = np.stack([_nanmean(fixed[:, :, g], 2) for g in groups], 2) if groups else resampled[..., :0]
    low, high = _interval(pred_res)
    counts = np.stack([(~np.isnan(point[:, g])).sum(1) for g in groups], 1)
    out["predicate"] = {
        "value": pred_point,
        "low": low,
        "high": high,
        "count": counts,
        "defined": _complete(point, resampled, groups),
    }
    layer_res = _nanmean(fixed, 2)
    low, high = _interval(layer_res)
    out["layer"] = {
        "value": _nanmean(point, 1),
        "low": low,
        "high": high,
        "count": (~np.isnan(point)).sum(1),
        "defined": _complete(point, resampled, [np.arange(point.shape[1])])[:, 0],
    }
    return out
