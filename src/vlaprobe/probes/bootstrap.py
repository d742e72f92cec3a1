"""The episode bootstrap every vlaprobe interval uses: resampling weights, percentile intervals, missing values.

One implementation for ``vlaprobe train`` (``evaluation.json``), ``vlaprobe hypotheses``, ``vlaprobe
compare-stores`` and ``vlaprobe cognition``:

- **Resamples** draw whole groups (test episodes) with replacement, as many as there are groups:
  :func:`bootstrap_weights` gives each resample's multiplicity of every group. A figure's value in a resample
  is its value on the weighted per-group sums (counts, cells), so resampling never touches the rows.
  The rows of a draw do not depend on how many are drawn: the first B of a draw of R >= B resamples are the
  draw of B (``vlaprobe train`` draws max(bootstrap, auprc_bootstrap) and uses the first ``bootstrap`` for the
  count metrics; ``vlaprobe hypotheses`` draws ``bootstrap`` with the same seed and gets the same resamples).
- **Intervals** are the 2.5th and 97.5th percentiles over the resamples (numpy's default linear method).
- **Missing values**: NaN marks a figure undefined in a resample (e.g. a balanced accuracy whose resample lacks
  a class). Percentiles are taken over the resamples that define the figure, and an interval needs at least
  :data:`MIN_DEFINED` of them, else it is NaN (``None`` in the JSON files).

Plain numpy (no torch), so the cognition layer can use it too.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

INTERVAL = (2.5, 97.5)
"""Percentiles of the 95% interval."""
MIN_DEFINED = 2
"""Fewest resamples defining a figure for it to get an interval."""


@dataclass(frozen=True)
class Estimate:
    """A figure (a mean balanced accuracy, a difference of two, a failure predictor's ROC-AUC, ...) with its 95%
    bootstrap interval (None where undefined)."""

    value: float | None
    low: float | None
    high: float | None


def bootstrap_weights(num_groups: int, resamples: int, seed: int) -> np.ndarray:
    """(resamples, groups) multiplicities of groups drawn with replacement, as many as there are groups.

    Row r is the same for every ``resamples`` > r (the draws are sequential in one generator)."""
    rng = np.random.default_rng(seed)
    return rng.multinomial(num_groups, np.full(num_groups, 1.0 / num_groups), size=resamples).astype(
        np.float64
    )


def resample_sums(weights: np.ndarray, per_group: np.ndarray) -> np.ndarray:
    """(resamples, ...) weighted sums over groups of ``per_group`` (groups, ...): its value in every resample."""
    return np.tensordot(weights, per_group, axes=(1, 0)) if per_group.ndim > 1 else weights @ per_group


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


def percentile_interval(resampled: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(low, high): the 95% percentile interval over axis 0 (the resamples) of every other entry, over the
    resamples that define it; NaN where fewer than :data:`MIN_DEFINED` do."""
    resampled = np.asarray(resampled, np.float64)
    if resampled.shape[0] < MIN_DEFINED:
        nan = np.full(resampled.shape[1:], np.nan)
        return nan, nan
    ok = (~np.isnan(resampled)).sum(0) >= MIN_DEFINED
    low, high = nan_percentiles(resampled, INTERVAL)
    return np.where(ok, low, np.nan), np.where(ok, high, np.nan)


def interval(resampled: np.ndarray) -> tuple[float, float]:
    """:func:`percentile_interval` of one figure's (resamples,) values, as two floats (NaN: undefined)."""
    low, high = percentile_interval(np.asarray(resampled, np.float64).reshape(-1, 1))
    return float(low[0]), float(high[0])


def nan_mean(x: np.ndarray, axis: int) -> np.ndarray:
    """Mean over ``axis`` of the defined (non-NaN) entries; NaN where none is defined (without a warning)."""
    defined = ~np.isnan(x)
    with np.errstate(invalid="ignore"):
        return np.where(defined.any(axis), np.nansum(x, axis) / defined.sum(axis), np.nan)


def nan_std(x: np.ndarray, axis: int) -> np.ndarray:
    """Population standard deviation over ``axis`` of the defined entries (NaN where none is)."""
    mean = nan_mean(x, axis)
    return np.sqrt(nan_mean((x - np.expand_dims(mean, axis)) ** 2, axis))
