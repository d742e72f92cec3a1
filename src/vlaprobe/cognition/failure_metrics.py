"""The metrics of failure prediction, on per-step scores of whole episodes: plain numpy, checked on synthetic
scores with known answers (tests/cognition/test_failure_metrics.py).

- **Running score**: the mean of a predictor's per-step scores from the first row to the current one (it uses
  nothing after the current row, as a live monitor could).
- **Functional conformal band** (SAFE's time-varying threshold, after Diquigiovanni et al.'s functional
  conformal prediction): on successful calibration episodes, the band μ(t) + h·σ(t), with μ and σ the mean and
  standard deviation of their running scores at step t and h the ⌈(n+1)(1-α)⌉-th smallest of their largest
  standardised excursions max_t (r(t) - μ(t)) / σ(t). A new successful episode exchangeable with them crosses
  the band somewhere with probability at most α.
- **ROC-AUC** at a normalised time τ: of the running scores at row ⌊τ·(T-1)⌋ of each episode, failures against
  successes (Mann-Whitney, ties counting half), with episode weights for the bootstrap; :func:`roc_curve` the
  curve whose area that is.
- **Score bands** over normalised time: the median and quartiles of the running scores of a group of episodes
  at each normalised time (SAFE's score-vs-time plots).
"""

from __future__ import annotations

import math
import warnings
from collections.abc import Sequence

import numpy as np

SIGMA_FLOOR = 1e-6
"""Least band width: a step at which every calibration episode scores the same."""


def running_mean(scores: np.ndarray) -> np.ndarray:
    """The mean of ``scores[:t+1]`` at every t."""
    scores = np.asarray(scores, np.float64)
    return np.cumsum(scores) / np.arange(1, len(scores) + 1)


def _pad(curves: Sequence[np.ndarray], length: int) -> np.ndarray:
    """(episodes, length) with NaN after each curve's end."""
    out = np.full((len(curves), length), np.nan)
    for i, c in enumerate(curves):
        out[i, : min(len(c), length)] = c[:length]
    return out


def _extend(values: np.ndarray) -> np.ndarray:
    """Fill NaN steps with the last defined value (steps no calibration episode reached)."""
    out = values.copy()
    for t in range(1, len(out)):
        if not np.isfinite(out[t]):
            out[t] = out[t - 1]
    return out


def conformal_band(calibration: Sequence[np.ndarray], alpha: float, length: int) -> np.ndarray:
    """The (length,) threshold per step from the running scores of successful calibration episodes (see the
    module docstring); +inf everywhere when there are too few of them for ``alpha`` (n < 1/α - 1)."""
    if not calibration:
        return np.full(length, np.inf)
    curves = _pad(calibration, length)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)  # steps no calibration episode reached
        mu = _extend(np.nanmean(curves, 0))
        sigma = _extend(np.nanstd(curves, 0))
    sigma = np.maximum(np.nan_to_num(sigma, nan=SIGMA_FLOOR), SIGMA_FLOOR)
    excursions = np.nanmax((curves - mu) / sigma, axis=1)
    n = len(excursions)
    rank = math.ceil((n + 1) * (1 - alpha))
    if rank > n:
        return np.full(length, np.inf)
    h = float(np.sort(excursions)[rank - 1])
    return mu + h * sigma


def first_alarm(running: np.ndarray, band: np.ndarray) -> int | None:
    """The first row whose running score is above the band (None: never)."""
    above = np.flatnonzero(np.asarray(running) > band[: len(running)])
    return int(above[0]) if len(above) else None


def alarm_onsets(running: np.ndarray, band: np.ndarray) -> int:
    """Alarms raised over an episode: rows above the band whose previous row was not."""
    above = np.asarray(running) > band[: len(running)]
    return int(above[0]) + int(np.sum(above[1:] & ~above[:-1])) if len(above) else 0


def weighted_auc(scores: np.ndarray, failed: np.ndarray, weights: np.ndarray | None = None) -> float:
    """ROC-AUC of ``scores`` for the positive class ``failed`` (ties count half), each episode counted
    ``weights`` times; NaN when a class is missing."""
    scores, failed = np.asarray(scores, np.float64), np.asarray(failed, bool)
    w = np.ones(len(scores)) if weights is None else np.asarray(weights, np.float64)
    pos, neg = scores[failed], scores[~failed]
    wp, wn = w[failed], w[~failed]
    total = wp.sum() * wn.sum()
    if total == 0:
        return math.nan
    diff = pos[:, None] - neg[None, :]
    wins = (diff > 0) + 0.5 * (diff == 0)
    return float(wp @ wins @ wn / total)


def at_time(curves: Sequence[np.ndarray], tau: float) -> np.ndarray:
    """Each curve's value at row ⌊τ·(T-1)⌋ (normalised time τ in [0, 1])."""
    return np.array([c[math.floor(tau * (len(c) - 1))] for c in curves])


def weighted_median(values: np.ndarray, weights: np.ndarray) -> float:
    """The median of ``values`` repeated ``weights`` times (integer bootstrap multiplicities); NaN if empty."""
    keep = weights > 0
    if not keep.any():
        return math.nan
    return float(np.median(np.repeat(values[keep], weights[keep].astype(np.int64))))


def roc_curve(scores: np.ndarray, failed: np.ndarray) -> tuple[list[float], list[float]]:
    """(false-positive rates, true-positive rates) of every threshold on ``scores``, from (0, 0) to (1, 1); tied
    scores make one diagonal step, so the trapezoid area under it is :func:`weighted_auc`. Empty when a class
    is missing."""
    scores, failed = np.asarray(scores, np.float64), np.asarray(failed, bool)
    pos, neg = int(failed.sum()), int((~failed).sum())
    if pos == 0 or neg == 0:
        return [], []
    fpr, tpr = [0.0], [0.0]
    for threshold in np.unique(scores)[::-1]:
        at = scores >= threshold
        fpr.append(float((at & ~failed).sum() / neg))
        tpr.append(float((at & failed).sum() / pos))
    return fpr, tpr


def score_bands(
    curves: Sequence[np.ndarray], taus: Sequence[float]
) -> tuple[list[float], list[float], list[float]]:
    """(25th percentile, median, 75th percentile) of the curves' values at each normalised time; empty when
    there are no curves."""
    if not curves:
        return [], [], []
    values = np.stack([at_time(curves, tau) for tau in taus])  # (times, episodes)
    q = np.percentile(values, [25, 50, 75], axis=1)
    return [float(x) for x in q[0]], [float(x) for x in q[1]], [float(x) for x in q[2]]
