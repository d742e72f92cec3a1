"""Layers statistically tied with the best one: a paired bootstrap over the same test-episode resamples.

The argmax of a flat curve is not a reproducible quantity (layers 0.0007 apart swap places on another
machine), so beside the best layer every head names the set of layers that are **not below the best
beyond a paired interval**: for each layer l, the 95 % percentile interval of BA(best) - BA(l) over the
resamples that give ``evaluation.json`` its intervals (both terms from the same resample, so their
correlation cancels). Layer l is tied when that interval holds 0 (its lower end is <= 0); the best layer
is always in the set. A layer whose difference is defined in fewer than 2 resamples cannot be told apart and
counts as tied. Plain numpy on (resamples, layers) arrays, so any curve can be tested::

    from vlaprobe.probes.ties import tie_set
    tied = tie_set(point, resampled, best)      # positions into the layers axis, ascending
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from vlaprobe.probes.bootstrap import nan_percentiles
from vlaprobe.probes.metrics import fixed_set

TIE_RULE = (
    "layers whose paired 95% bootstrap interval of (best minus layer), over the same test-episode "
    "resamples, holds 0"
)
"""The rule, in words, stored next to the set."""


def layer_resamples(point: np.ndarray, resampled: np.ndarray) -> np.ndarray:
    """(resamples, layers) per-layer means over the atoms, in each resample, over the fixed set of atoms of
    :func:`~vlaprobe.probes.metrics.fixed_set` (the resamples behind ``summarize``'s layer intervals).

    ``point`` is (layers, atoms), ``resampled`` (resamples, layers, atoms)."""
    fixed = fixed_set(point, resampled)
    defined = ~np.isnan(fixed)
    with np.errstate(invalid="ignore"):
        return np.where(defined.any(2), np.nansum(fixed, 2) / defined.sum(2), np.nan)


def paired_differences(resampled: np.ndarray, best: int) -> tuple[np.ndarray, np.ndarray]:
    """2.5th and 97.5th percentiles (layers,) of ``resampled[:, best] - resampled[:, l]`` over the
    resamples (rows of the (resamples, layers) array); NaN where fewer than 2 resamples define it."""
    diff = resampled[:, [best]] - resampled
    if diff.shape[0] < 2:
        nan = np.full(diff.shape[1], np.nan)
        return nan, nan
    low, high = nan_percentiles(diff, (2.5, 97.5))
    enough = (~np.isnan(diff)).sum(0) >= 2
    return np.where(enough, low, np.nan), np.where(enough, high, np.nan)


def tie_set(point: np.ndarray, resampled: np.ndarray, best: int) -> list[int]:
    """Positions (ascending, ``best`` included) of the layers tied with ``best``.

    ``point`` (layers,) is the curve on the full test set, ``resampled`` (resamples, layers) the same curve
    in each bootstrap resample. A layer undefined at the point (NaN) is never tied."""
    point = np.asarray(point, float)
    low, _ = paired_differences(np.asarray(resampled, float), best)
    tied = ~np.isnan(point) & (np.isnan(low) | (low <= 0))
    tied[best] = True
    return [int(i) for i in np.flatnonzero(tied)]


def ranges(layers: Sequence[int]) -> str:
    """Sorted layer indices as runs: [8, 9, 10, 12, 27, 28] -> "8-10, 12, 27-28"."""
    runs: list[list[int]] = []
    for layer in sorted(layers):
        if runs and layer == runs[-1][-1] + 1:
            runs[-1].append(layer)
        else:
            runs.append([layer])
    return ", ".join(str(r[0]) if len(r) == 1 else f"{r[0]}-{r[-1]}" for r in runs)


def describe(best: int, tied: Sequence[int]) -> str:
    """ "best layer 30, tied with 8-12, 27-32" (the set includes the best), or "..., no layer tied with it"."""
    others = [t for t in tied if t != best]
    if not others:
        return f"best layer {best}, no other layer tied with it"
    return f"best layer {best}, tied with {ranges(sorted({*tied, best}))}"
