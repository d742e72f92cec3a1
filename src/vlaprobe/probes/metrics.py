"""Classification metrics per (layer, atom), their episode-bootstrap resamples, and averages per predicate.

The one implementation of confusion counts, accuracy, balanced accuracy, F1 and AUPRC in vlaprobe
(``vlaprobe train``, ``hypotheses``, ``compare-stores``); resampling and intervals are in
:mod:`vlaprobe.probes.bootstrap`.

Counts first: per test episode, layer and atom the confusion counts, always in the order (tp, fp, fn, tn)
(:data:`COUNTS`). A bootstrap resample draws test episodes with replacement, so its counts are a weighted sum
of the per-episode counts and accuracy, balanced accuracy and F1 of a thousand resamples cost one small
matmul. AUPRC needs the ranking of scores: every column is sorted once and each resample only reweights the
sorted rows.

**Balanced accuracy** is the mean of the recall of the positives and the recall of the negatives, and it is
**defined only where the scored rows hold both classes**. An atom with a single class on the scored rows (all
test steps false, say) has no balanced accuracy: it is NaN, left out of averages (``count`` says how many
atoms an average covers). The rule is the same on the full test set and in every resample (a resample that
draws none of an atom's positive episodes leaves its balanced accuracy undefined there), so point values and
intervals agree on which atoms they are about. (scikit-learn's ``balanced_accuracy_score`` instead returns the
recall of the one class present, with a warning; on rows holding both classes the two agree.)

F1 and AUPRC are undefined without a positive row (whatever the false positives); accuracy always is defined.
Undefined is NaN everywhere; :func:`summarize` reports how many atoms each average covers and in how many
resamples each figure was defined.
"""

from __future__ import annotations

import numpy as np
import torch
import torch.nn.functional as F

from vlaprobe.probes.bootstrap import nan_mean, percentile_interval, resample_sums

METRICS = ("accuracy", "balanced_accuracy", "f1", "auprc")
"""Every metric reported, in display order."""
COUNT_METRICS = ("accuracy", "balanced_accuracy", "f1")
"""Metrics computed from confusion counts."""
COUNTS = ("tp", "fp", "fn", "tn")
"""The order of the last axis of every confusion-count array."""


def confusion_by_group(
    pred: torch.Tensor | np.ndarray,
    truth: np.ndarray,
    groups: np.ndarray,
    num_groups: int,
    defined: np.ndarray | None = None,
) -> np.ndarray:
    """Confusion counts (groups, layers, atoms, 4 = tp, fp, fn, tn) of bool ``pred`` (layers, rows, atoms).

    ``truth`` is bool (rows, atoms); ``groups`` int (rows,) in [0, num_groups), e.g. the test episode.
    ``defined`` (rows, atoms) bool, when given, leaves out the entries where it is False (an atom undefined in
    the row's task: counted in no cell, never as false).
    """
    pred = torch.as_tensor(np.asarray(pred) if isinstance(pred, np.ndarray) else pred).bool()
    truth_t = torch.as_tensor(np.asarray(truth, bool))
    index = torch.as_tensor(np.asarray(groups), dtype=torch.long)
    atoms = pred.shape[2]
    mask = None if defined is None else torch.as_tensor(np.asarray(defined, bool))
    if mask is not None:
        pred, truth_t = pred & mask[None], truth_t & mask

    def group_sum(x: torch.Tensor) -> torch.Tensor:  # (layers, rows, atoms) -> (groups, layers, atoms)
        out = torch.zeros((num_groups, x.shape[0], atoms), dtype=torch.float64)
        return out.index_add_(0, index, x.permute(1, 0, 2).double())

    tp = group_sum(pred & truth_t)
    predicted = group_sum(pred)
    positives = group_sum(truth_t[None])
    sizes = (
        torch.bincount(index, minlength=num_groups).double()[:, None, None]
        if mask is None
        else group_sum(mask[None])
    )
    fp, fn = predicted - tp, positives - tp
    tn = sizes - tp - fp - fn
    return torch.stack([tp, fp, fn, tn.expand_as(tp)], dim=-1).numpy()


def metrics_from_counts(counts: np.ndarray) -> dict[str, np.ndarray]:
    """accuracy, balanced accuracy (undefined unless both classes are present) and F1 (undefined without a
    positive step, whatever the false positives) from (..., 4) counts in :data:`COUNTS` order."""
    tp, fp, fn, tn = (np.asarray(counts, np.float64)[..., i] for i in range(4))
    positives, negatives = tp + fn, tn + fp
    with np.errstate(invalid="ignore", divide="ignore"):
        accuracy = (tp + tn) / (positives + negatives)
        both = (positives > 0) & (negatives > 0)
        balanced = np.where(both, 0.5 * (tp / positives + tn / negatives), np.nan)
        f1 = np.where(positives > 0, 2 * tp / (2 * tp + fp + fn), np.nan)
    return {"accuracy": accuracy, "balanced_accuracy": balanced, "f1": f1}


def count_metrics(
    counts: np.ndarray, weights: np.ndarray
) -> tuple[dict[str, np.ndarray], dict[str, np.ndarray]]:
    """:data:`COUNT_METRICS` on all groups, (...), and in every resample of ``weights``, (resamples, ...),
    from per-group counts (groups, ..., 4) and (resamples, groups) multiplicities
    (:func:`~vlaprobe.probes.bootstrap.bootstrap_weights`)."""
    return metrics_from_counts(counts.sum(0)), metrics_from_counts(resample_sums(weights, counts))


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


def atom_metrics(
    logits: torch.Tensor,
    truth: np.ndarray,
    groups: np.ndarray,
    num_groups: int,
    threshold_logit: float,
    weights: np.ndarray,
    auprc_resamples: int,
    defined: np.ndarray | None = None,
) -> tuple[dict[str, np.ndarray], dict[str, np.ndarray]]:
    """Point values (layers, atoms) and bootstrap resamples (resamples, layers, atoms) of every metric.

    Predictions are ``logits > threshold_logit``; AUPRC ranks the logits. AUPRC resamples are the first
    ``auprc_resamples`` rows of ``weights`` (an empty array when 0). ``defined`` (rows, atoms) bool, when
    given, leaves out the undefined entries from every metric (for AUPRC they rank below every scored row, as
    negatives: they enter no precision).
    """
    counts = confusion_by_group(logits > threshold_logit, truth, groups, num_groups, defined)
    point, resampled = count_metrics(counts, weights)
    layers, _, atoms = logits.shape
    truth = np.asarray(truth, bool)
    if defined is not None:
        mask = torch.as_tensor(np.asarray(defined, bool))
        logits = torch.where(mask[None], logits.double(), -torch.inf)
        truth = truth & defined
    columns = logits.permute(1, 0, 2).reshape(logits.shape[1], layers * atoms)
    truth_cols = torch.as_tensor(truth).repeat(1, layers)
    point["auprc"] = average_precision(columns, truth_cols).reshape(layers, atoms).numpy()
    group_weights = weights[:auprc_resamples]
    resampled["auprc"] = np.empty((len(group_weights), layers, atoms))
    if len(group_weights):
        for a in range(atoms):  # one atom at every layer: the same positives
            resampled["auprc"][:, :, a] = resampled_average_precision(
                logits[:, :, a].T, truth[:, a], groups, group_weights
            )
    return point, resampled


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


def layer_means(point: np.ndarray, resampled: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Per layer, the mean over atoms of ``point`` (layers, atoms) and of every resample (resamples, layers,
    atoms), over the fixed set of :func:`fixed_set`: the curve of ``evaluation.json``'s ``layer`` level and
    of ``vlaprobe hypotheses``. Returns (layers,) and (resamples, layers)."""
    return nan_mean(point, 1), nan_mean(fixed_set(point, resampled), 2)


def summarize(
    point: np.ndarray, resampled: np.ndarray, groups: list[np.ndarray]
) -> dict[str, dict[str, np.ndarray]]:
    """Per atom, per predicate (mean over ``groups`` of atom columns) and per layer (mean over all atoms).

    ``point`` is (layers, atoms), ``resampled`` (resamples, layers, atoms). Each level gets its value and a
    95% percentile interval computed from the same resamples (so intervals of averages are correct, not
    averages of intervals; averages over the fixed set of :func:`fixed_set`); ``count`` says how many atoms
    were defined in each average and ``defined`` in how many resamples the figure was defined over all of its
    atoms (an atom: in which it was defined).
    """
    out: dict[str, dict[str, np.ndarray]] = {}
    low, high = percentile_interval(resampled)
    fixed = fixed_set(point, resampled)
    out["atom"] = {"value": point, "low": low, "high": high, "defined": (~np.isnan(resampled)).sum(0)}
    pred_point = np.stack([nan_mean(point[:, g], 1) for g in groups], 1)
    pred_res = np.stack([nan_mean(fixed[:, :, g], 2) for g in groups], 2) if groups else resampled[..., :0]
    low, high = percentile_interval(pred_res)
    counts = np.stack([(~np.isnan(point[:, g])).sum(1) for g in groups], 1)
    out["predicate"] = {
        "value": pred_point,
        "low": low,
        "high": high,
        "count": counts,
        "defined": _complete(point, resampled, groups),
    }
    layer_point, layer_res = layer_means(point, resampled)
    low, high = percentile_interval(layer_res)
    out["layer"] = {
        "value": layer_point,
        "low": low,
        "high": high,
        "count": (~np.isnan(point)).sum(1),
        "defined": _complete(point, resampled, [np.arange(point.shape[1])])[:, 0],
    }
    return out
