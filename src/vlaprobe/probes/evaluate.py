"""Scoring trained probes on held-out episodes: cross-fitting, every metric with intervals, controls.

:func:`cross_fit` trains on each fold's training rows (with the shuffled-label permutations as extra columns
of the same matmuls) and scores its test rows; :func:`evaluate_head` turns one head's scores into a
:class:`~vlaprobe.probes.results.HeadResult` (probes, majority baseline, shuffled-label control with its
spread over permutations, selectivity, best layer).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch

from vlaprobe.configs.train import TrainConfig
from vlaprobe.probes.data import ACTION_PREDICATES, OBJECT_PREDICATES, ProbeData, predicate
from vlaprobe.probes.metrics import COUNT_METRICS, METRICS, atom_metrics, summarize
from vlaprobe.probes.results import (
    BestLayer,
    DroppedAtom,
    HeadResult,
    Level,
    MetricSummary,
    Spread,
    nested,
    number,
)
from vlaprobe.probes.split import LabelFilter
from vlaprobe.probes.trainer import LinearProbes, fit_probes


@dataclass
class CrossFit:
    """Held-out scores pooled over folds."""

    rows: np.ndarray
    """Sorted held-out rows (every test row of every fold)."""
    logits: torch.Tensor
    """(layers, rows, atoms) probe logits."""
    control_logits: torch.Tensor | None
    """(permutations, layers, rows, atoms) logits of the probes trained on shuffled labels, or None."""
    majority: np.ndarray
    """bool (rows, atoms): the majority class of each row's training split."""
    groups: np.ndarray
    """(rows,) test-episode index of each row, for the bootstrap."""
    episodes: np.ndarray
    """Episode positions of the groups."""
    probes: LinearProbes
    """The last fold's probes (the real columns only)."""
    train_frequency: np.ndarray
    """(atoms,) share of true rows in the training splits (mean over folds)."""

    @property
    def num_groups(self) -> int:
        return len(self.episodes)


def cross_fit(
    data: ProbeData,
    targets: np.ndarray,
    fold_rows: list[tuple[np.ndarray, np.ndarray]],
    cfg: TrainConfig,
    seeds: dict[str, int],
    permutations: int,
) -> CrossFit:
    """Train on each fold's training rows, score its test rows; pool the scores over folds.

    Each of ``permutations`` shuffled-label controls permutes the training labels across steps (whole label
    rows, so the atoms' co-occurrence is kept) and adds a block of columns to the same matmuls: it costs
    only wider weights.
    """
    rng = np.random.default_rng(seeds["shuffle"])
    k = targets.shape[1]
    eval_rows = np.sort(np.concatenate([te for _, te in fold_rows]))
    logits = torch.empty((len(data.layers), len(eval_rows), k))
    control = torch.empty((permutations, *logits.shape)) if permutations else None
    majority = np.empty((len(eval_rows), k), bool)
    train_frequency = np.zeros(k)
    probes: LinearProbes | None = None
    for i, (train_rows, test_rows) in enumerate(fold_rows):
        blocks = [targets]
        for _ in range(permutations):
            shuffled = np.zeros_like(targets)
            shuffled[train_rows] = targets[rng.permutation(train_rows)]
            blocks.append(shuffled)
        fitted = fit_probes(
            data.hidden, np.concatenate(blocks, axis=1), train_rows, cfg.probe, seeds["probe"] + i
        )
        scores = fitted.logits(data.hidden, test_rows)
        at = np.searchsorted(eval_rows, test_rows)
        logits[:, at] = scores[:, :, :k]
        if control is not None:
            for p in range(permutations):
                control[p][:, at] = scores[:, :, k * (p + 1) : k * (p + 2)]
        frequency = targets[train_rows].mean(0)
        majority[at] = frequency >= 0.5
        train_frequency += frequency / len(fold_rows)
        probes = LinearProbes(fitted.weight[:, :, :k], fitted.bias[:, :k], fitted.mean, fitted.std)
    assert probes is not None
    episodes, groups = np.unique(data.episode[eval_rows], return_inverse=True)
    return CrossFit(eval_rows, logits, control, majority, groups, episodes, probes, train_frequency)


def predicate_order(atoms: list[str]) -> list[str]:
    """Predicates of ``atoms`` in the paper's figure order; unknown predicates follow, sorted."""
    present = {predicate(a) for a in atoms}
    known = [p for p in (*OBJECT_PREDICATES, *ACTION_PREDICATES) if p in present]
    return known + sorted(present - set(known))


def _summary(point: np.ndarray, resampled: np.ndarray, groups: list[np.ndarray]) -> MetricSummary:
    s = summarize(point, resampled, groups)

    def level(name: str) -> Level:
        x = s[name]
        count = nested(x["count"]) if "count" in x else None
        return Level(nested(x["value"]), nested(x["low"]), nested(x["high"]), nested(x["defined"]), count)

    return MetricSummary(atom=level("atom"), predicate=level("predicate"), layer=level("layer"))


def _nanmean(x: np.ndarray, axis: int) -> np.ndarray:
    defined = ~np.isnan(x)
    with np.errstate(invalid="ignore"):
        return np.where(defined.any(axis), np.nansum(x, axis) / defined.sum(axis), np.nan)


def _nanstd(x: np.ndarray, axis: int) -> np.ndarray:
    mean = _nanmean(x, axis)
    return np.sqrt(_nanmean((x - np.expand_dims(mean, axis)) ** 2, axis))


def best_layer(
    layer_values: np.ndarray, low: np.ndarray, high: np.ndarray, layers: list[int], metric: str
) -> BestLayer:
    """Layer with the highest mean ``metric`` over the head's atoms (first one on ties)."""
    i = 0 if np.all(np.isnan(layer_values)) else int(np.nanargmax(layer_values))
    return BestLayer(
        layer=layers[i],
        index=i,
        metric=metric,
        value=number(layer_values[i]),
        low=number(low[i]),
        high=number(high[i]),
        rule=f"highest mean {metric} over the head's probed atoms on held-out episodes",
    )


def evaluate_head(
    head: str,
    data: ProbeData,
    filt: LabelFilter,
    cols: np.ndarray,
    fitted: CrossFit,
    targets: np.ndarray,
    weights: np.ndarray,
    threshold_logit: float,
    cfg: TrainConfig,
) -> HeadResult:
    """All metrics of one head: probes, majority baseline, shuffled control, selectivity, best layer."""
    atoms = [data.atom_names[head][j] for j in filt.kept]
    preds = predicate_order(atoms)
    groups = [np.array([i for i, a in enumerate(atoms) if predicate(a) == p]) for p in preds]
    truth = targets[fitted.rows][:, cols]
    count_weights = weights[: cfg.bootstrap]

    def run(logits: torch.Tensor, auprc_resamples: int) -> tuple[dict, dict]:
        point, res = atom_metrics(
            logits, truth, fitted.groups, fitted.num_groups, threshold_logit, weights, auprc_resamples
        )
        for m in COUNT_METRICS:
            res[m] = res[m][: len(count_weights)]
        return point, res

    point, res = run(fitted.logits[:, :, cols], cfg.auprc_bootstrap)
    probe = {m: _summary(point[m], res[m], groups) for m in METRICS}
    baseline_logits = (
        torch.where(torch.as_tensor(fitted.majority[:, cols]), 1.0, -1.0)[None] + threshold_logit
    )
    b_point, b_res = run(baseline_logits, 0)
    result = HeadResult(
        atoms=atoms,
        predicates=preds,
        predicate_atoms={p: [atoms[i] for i in g] for p, g in zip(preds, groups, strict=True)},
        skipped_predicates=sorted(
            {predicate(a) for a in data.atom_names[head]} - set(preds),
            key=lambda p: predicate_order([f"{p}()", *atoms]).index(p),
        ),
        dropped=[DroppedAtom(**d) for d in filt.dropped],
        train_frequency=nested(fitted.train_frequency[cols]),
        test_frequency=nested(truth.mean(0)),
        best=BestLayer(0, 0, "", None, None, None, ""),
        probe=probe,
        baseline={m: _summary(b_point[m], b_res[m], groups) for m in METRICS},
    )
    if fitted.control_logits is not None:
        runs = [run(c[:, :, cols], 0) for c in fitted.control_logits]
        c_point = {m: np.mean([r[0][m] for r in runs], axis=0) for m in METRICS}
        c_res = {m: np.mean([r[1][m] for r in runs], axis=0) for m in METRICS}
        result.control = {m: _summary(c_point[m], c_res[m], groups) for m in METRICS}
        result.control_spread = {}
        for m in METRICS:
            per_perm = np.stack([r[0][m] for r in runs])  # (permutations, layers, atoms)
            by_pred = np.stack([_nanmean(per_perm[:, :, g], 2) for g in groups], 2)
            result.control_spread[m] = Spread(
                predicate=nested(_nanstd(by_pred, 0)), layer=nested(_nanstd(_nanmean(per_perm, 2), 0))
            )
        result.selectivity = {
            m: _summary(point[m] - c_point[m], res[m] - c_res[m], groups) for m in COUNT_METRICS
        }
    s = summarize(point[cfg.select_metric], res[cfg.select_metric], groups)["layer"]
    result.best = best_layer(s["value"], s["low"], s["high"], data.layers, cfg.select_metric)
    return result
