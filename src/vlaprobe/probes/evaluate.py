"""Scoring trained probes on held-out episodes: cross-fitting, every metric with intervals, controls.

:func:`cross_fit` trains on each fold's training rows (with the shuffled-label permutations as extra columns
of the same matmuls) and scores its test rows; :func:`evaluate_head` turns one head's scores into a
:class:`~vlaprobe.probes.results.HeadResult` (probes, majority baseline, shuffled-label control with its
spread over permutations, selectivity, best layer).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import torch

from vlaprobe.configs.train import TrainConfig
from vlaprobe.probes.baselines import BASELINES, predict_baselines
from vlaprobe.probes.bootstrap import nan_mean, nan_std
from vlaprobe.probes.conditional import ConditionalFit, evaluate_conditional
from vlaprobe.probes.data import ACTION_PREDICATES, OBJECT_PREDICATES, ProbeData, predicate
from vlaprobe.probes.metrics import COUNT_METRICS, METRICS, atom_metrics, summarize
from vlaprobe.probes.regularization import ColumnGroups
from vlaprobe.probes.results import (
    BestLayer,
    DroppedAtom,
    HeadResult,
    MetricSummary,
    ProbeFit,
    Spread,
    level,
    nested,
    number,
)
from vlaprobe.probes.split import LabelFilter, defined_frequency
from vlaprobe.probes.ties import TIE_RULE, layer_resamples, tie_set
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
    baselines: dict[str, np.ndarray]
    """Baseline name (:data:`~vlaprobe.probes.baselines.BASELINES`) -> bool (rows, atoms): its prediction,
    fit on each row's training split."""
    groups: np.ndarray
    """(rows,) test-episode index of each row, for the bootstrap."""
    episodes: np.ndarray
    """Episode positions of the groups."""
    probes: LinearProbes
    """The last fold's probes (the real columns only)."""
    fold_probes: list[LinearProbes]
    """Every fold's probes (the real columns only; the last is ``probes``), e.g. for conditional probing."""
    train_frequency: np.ndarray
    """(atoms,) share of true rows in the training splits (mean over folds)."""
    column_head: np.ndarray
    """(atoms,) head index of each target column (the column group sharing an L2 strength)."""
    conditional: dict[str, ConditionalFit] = field(default_factory=dict)
    """Baseline name -> its conditional probes' held-out logits (:mod:`vlaprobe.probes.conditional`), when
    computed."""
    defined: np.ndarray | None = None
    """bool (rows, atoms): which held-out entries are defined (union stores; None: all). Every score leaves
    the others out."""

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
    column_head: np.ndarray,
    defined: np.ndarray | None = None,
) -> CrossFit:
    """Train on each fold's training rows, score its test rows; pool the scores over folds.

    Each of ``permutations`` shuffled-label controls permutes the training labels across steps (whole label
    rows, so the atoms' co-occurrence is kept) and adds a block of columns to the same matmuls: it costs
    only wider weights. ``column_head`` (atoms,) says which head each target column belongs to: a head's
    atoms (and their shuffled copies) share one L2 strength per layer. ``defined`` (steps, atoms) bool like
    ``targets``, when given: the undefined entries are left out of every fit, baseline and score (a shuffled
    row carries its own mask along).
    """
    rng = np.random.default_rng(seeds["shuffle"])
    k = targets.shape[1]
    eval_rows = np.sort(np.concatenate([te for _, te in fold_rows]))
    logits = torch.empty((len(data.layers), len(eval_rows), k))
    control = torch.empty((permutations, *logits.shape)) if permutations else None
    baselines = {name: np.empty((len(eval_rows), k), bool) for name in BASELINES}
    train_frequency = np.zeros(k)
    fold_probes: list[LinearProbes] = []
    groups = column_groups(data, column_head, permutations, cfg.split.by == "leave-one-task-out")
    for i, (train_rows, test_rows) in enumerate(fold_rows):
        blocks = [targets]
        masks = [] if defined is None else [defined]
        for _ in range(permutations):
            shuffled, mask = shuffled_labels(targets, train_rows, rng, defined)
            blocks.append(shuffled)
            if mask is not None:
                masks.append(mask)
        fitted = fit_probes(
            data.hidden,
            np.concatenate(blocks, axis=1),
            train_rows,
            cfg.probe,
            seeds["probe"] + i,
            groups,
            defined=np.concatenate(masks, axis=1) if masks else None,
        )
        scores = fitted.logits(data.hidden, test_rows)
        at = np.searchsorted(eval_rows, test_rows)
        logits[:, at] = scores[:, :, :k]
        if control is not None:
            for p in range(permutations):
                control[p][:, at] = scores[:, :, k * (p + 1) : k * (p + 2)]
        predicted = predict_baselines(
            targets, data.episode, data.episode_tasks, train_rows, test_rows, defined=defined
        )
        for name in BASELINES:
            baselines[name][at] = predicted[name]
        train_mask = None if defined is None else defined[train_rows]
        train_frequency += defined_frequency(targets[train_rows], train_mask) / len(fold_rows)
        fold_probes.append(fitted.columns(slice(0, k)))
    episodes, groups = np.unique(data.episode[eval_rows], return_inverse=True)
    return CrossFit(
        eval_rows,
        logits,
        control,
        baselines,
        groups,
        episodes,
        fold_probes[-1],
        fold_probes,
        train_frequency,
        np.asarray(column_head),
        defined=None if defined is None else defined[eval_rows],
    )


def shuffled_labels(
    targets: np.ndarray, train_rows: np.ndarray, rng: np.random.Generator, defined: np.ndarray | None = None
) -> tuple[np.ndarray, np.ndarray | None]:
    """One shuffled-label control's targets: the label rows of ``train_rows`` permuted across those steps
    (whole rows, so the atoms' co-occurrence is kept; zeros elsewhere), with the ``defined`` mask carried
    along (None without one). One draw of ``rng`` per call: ``vlaprobe train`` and ``vlaprobe cross-suite``
    draw the same permutations from the same seed and rows."""
    order = rng.permutation(train_rows)
    shuffled = np.zeros_like(targets)
    shuffled[train_rows] = targets[order]
    if defined is None:
        return shuffled, None
    mask = np.zeros_like(defined)
    mask[train_rows] = defined[order]
    return shuffled, mask


def column_groups(
    data: ProbeData, column_head: np.ndarray, permutations: int, across_tasks: bool = False
) -> ColumnGroups:
    """Columns of the real atoms and of each shuffled copy, grouped by head; the real ones are scored.
    ``across_tasks``: the split tests unseen tasks (the C search's folds then hold out whole tasks)."""
    k = len(column_head)
    return ColumnGroups(
        episode=data.episode,
        episode_tasks=data.episode_tasks,
        group=np.tile(np.asarray(column_head), 1 + permutations),
        scored=np.arange(k * (1 + permutations)) < k,
        across_tasks=across_tasks,
    )


def probe_fit(fitted: CrossFit, cols: np.ndarray, cfg: TrainConfig) -> ProbeFit:
    """How the probes of one head (columns ``cols``) were fit, for ``evaluation.json``."""
    probes = fitted.probes
    conv = probes.convergence
    assert conv is not None and probes.c is not None
    conv = conv.columns(cols)
    cv_loss = cv_score = c_at_edge = None
    rule = "one C given, not cross-validated"
    if probes.cv is None and len(cfg.probe.c_grid) > 1:
        rule = (
            f"C = {cfg.probe.c_without_cv:g} (--probe.c-without-cv), not cross-validated: the training split "
            "leaves no fold to hold out (one training episode per task, or one task across tasks)"
        )
    if probes.cv is not None and len(cols):
        group = int(fitted.column_head[cols[0]])
        cv_loss = nested(probes.cv.of_group(group)[0])
        score = probes.cv.score_of(group)
        cv_score = None if score is None else nested(score)
        c_at_edge = [bool(e) for e in probes.cv.edge_of(group)]
        rule = (
            f"the smallest C whose mean held-out balanced accuracy over the head's atoms and {probes.cv.folds} "
            f"episode-grouped folds of the training split is within {probes.cv.tolerance:g} of the best C's"
            + (" (folds of whole tasks)" if cfg.split.by == "leave-one-task-out" else "")
        )
    return ProbeFit(
        tol=conv.tol,
        max_iter=conv.max_iter,
        standardized=probes.mean is not None,
        c=[float(c) for c in probes.c[:, cols[0]]] if len(cols) else [],  # not rounded: C may be < 1e-5
        c_grid=[float(c) for c in cfg.probe.c_grid],
        cv_folds=0 if probes.cv is None else probes.cv.folds,
        cv_loss=cv_loss,
        cv_score=cv_score,
        c_rule=rule,
        c_at_edge=c_at_edge,
        iterations=nested(conv.iterations),
        loss=nested(conv.loss),
        grad_norm=nested(conv.grad_norm),
        at_cap=int((~conv.converged & (conv.iterations >= conv.max_iter)).sum()),
        stalled=int((~conv.converged & (conv.iterations < conv.max_iter)).sum()),
        probes=int(conv.converged.size),
    )


def predicate_order(atoms: list[str]) -> list[str]:
    """Predicates of ``atoms`` in the paper's figure order; unknown predicates follow, sorted."""
    present = {predicate(a) for a in atoms}
    known = [p for p in (*OBJECT_PREDICATES, *ACTION_PREDICATES) if p in present]
    return known + sorted(present - set(known))


def _summary(point: np.ndarray, resampled: np.ndarray, groups: list[np.ndarray]) -> MetricSummary:
    s = summarize(point, resampled, groups)
    return MetricSummary(atom=level(s["atom"]), predicate=level(s["predicate"]), layer=level(s["layer"]))


def best_layer(
    layer_values: np.ndarray,
    low: np.ndarray,
    high: np.ndarray,
    layers: list[int],
    metric: str,
    layer_resampled: np.ndarray | None = None,
) -> BestLayer:
    """Layer with the highest mean ``metric`` over the head's atoms (first one on ties), and the layers tied
    with it (:func:`~vlaprobe.probes.ties.tie_set` on ``layer_resampled`` (resamples, layers); without
    resamples the best layer alone)."""
    i = 0 if np.all(np.isnan(layer_values)) else int(np.nanargmax(layer_values))
    tied = [i] if layer_resampled is None else tie_set(layer_values, layer_resampled, i)
    return BestLayer(
        layer=layers[i],
        index=i,
        metric=metric,
        value=number(layer_values[i]),
        low=number(low[i]),
        high=number(high[i]),
        rule=f"highest mean {metric} over the head's probed atoms on held-out episodes",
        tied=[layers[t] for t in tied],
        tie_rule=TIE_RULE,
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
    held = None if fitted.defined is None else fitted.defined[:, cols]
    count_weights = weights[: cfg.bootstrap]

    def run(logits: torch.Tensor, auprc_resamples: int) -> tuple[dict, dict]:
        point, res = atom_metrics(
            logits, truth, fitted.groups, fitted.num_groups, threshold_logit, weights, auprc_resamples, held
        )
        for m in COUNT_METRICS:
            res[m] = res[m][: len(count_weights)]
        return point, res

    point, res = run(fitted.logits[:, :, cols], cfg.auprc_bootstrap)
    probe = {m: _summary(point[m], res[m], groups) for m in METRICS}

    def baseline(name: str) -> tuple[dict, dict]:
        pred = torch.as_tensor(fitted.baselines[name][:, cols])
        return run(torch.where(pred, 1.0, -1.0)[None] + threshold_logit, 0)

    base = {name: baseline(name) for name in BASELINES}
    b_point, b_res = base["majority"]
    tt_point, tt_res = base["task_time"]
    t_point, t_res = base["time"]
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
        test_frequency=nested(defined_frequency(truth, held)),
        best=BestLayer(0, 0, "", None, None, None, ""),
        probe=probe,
        baseline={m: _summary(b_point[m], b_res[m], groups) for m in METRICS},
        time_baseline={m: _summary(t_point[m], t_res[m], groups) for m in METRICS},
        selectivity_time={
            m: _summary(point[m] - t_point[m], res[m] - t_res[m], groups) for m in COUNT_METRICS
        },
        task_baseline={m: _summary(base["task"][0][m], base["task"][1][m], groups) for m in METRICS},
        task_time_baseline={m: _summary(tt_point[m], tt_res[m], groups) for m in METRICS},
        selectivity_task_time={
            m: _summary(point[m] - tt_point[m], res[m] - tt_res[m], groups) for m in COUNT_METRICS
        },
    )
    if fitted.control_logits is not None:
        runs = [run(c[:, :, cols], 0) for c in fitted.control_logits]
        c_point = {m: np.mean([r[0][m] for r in runs], axis=0) for m in METRICS}
        c_res = {m: np.mean([r[1][m] for r in runs], axis=0) for m in METRICS}
        result.control = {m: _summary(c_point[m], c_res[m], groups) for m in METRICS}
        result.control_spread = {}
        for m in METRICS:
            per_perm = np.stack([r[0][m] for r in runs])  # (permutations, layers, atoms)
            by_pred = np.stack([nan_mean(per_perm[:, :, g], 2) for g in groups], 2)
            result.control_spread[m] = Spread(
                predicate=nested(nan_std(by_pred, 0)), layer=nested(nan_std(nan_mean(per_perm, 2), 0))
            )
        result.selectivity = {
            m: _summary(point[m] - c_point[m], res[m] - c_res[m], groups) for m in COUNT_METRICS
        }
    result.fit = probe_fit(fitted, cols, cfg)
    conditional = {
        name: evaluate_conditional(
            cf, cols, truth, fitted.groups, fitted.num_groups, threshold_logit, count_weights, groups, held
        )
        for name, cf in fitted.conditional.items()
    }
    result.conditional_task = conditional.get("task")
    result.conditional_task_time = conditional.get("task_time")
    m = cfg.select_metric
    s = summarize(point[m], res[m], groups)["layer"]
    resampled = layer_resamples(point[m], res[m])
    result.best = best_layer(s["value"], s["low"], s["high"], data.layers, m, resampled)
    return result
