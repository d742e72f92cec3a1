"""Conditional probing: the information a layer adds beyond a baseline (Hewitt et al., EMNLP 2021).

"Conditional probing: measuring usable information beyond a baseline": the usable information a
representation adds beyond baseline features is the gain of a probe on [baseline features + representation]
over a probe on [baseline features] alone. Here the baseline features are the one-hot cell of a row under
the task baseline (its task) and the task x time baseline (task x decile of normalised episode time, the
cells of :mod:`vlaprobe.probes.baselines`), and the representation is the layer's hidden state,
standardised with the training split's statistics (the one-hot columns stay 0/1). The one-hot block is
unpenalised in both probes (the features-only probe is then the cells' log-odds, the cell majority's
scores); the hidden-state block is penalised with the C the probes' own search chose at that layer and head
on the same fold, so no second search is run. Both are fit by the probes' batched solver
(:func:`~vlaprobe.probes.trainer.fit_probes`) on the same folds and scored on the same held-out rows, with
the same bootstrap resamples: the gain's interval is paired.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import numpy as np
import torch

from vlaprobe.configs.train import TrainConfig
from vlaprobe.probes.baselines import TIME_BINS, time_bin
from vlaprobe.probes.metrics import atom_metrics, summarize
from vlaprobe.probes.results import ConditionalProbe, level, number
from vlaprobe.probes.trainer import LinearProbes, fit_probes

CONDITIONAL_BASELINES = ("task", "task_time")
"""Baselines conditioned on, coarsest first (names of :data:`~vlaprobe.probes.baselines.BASELINES`)."""
CONDITIONAL_METRIC = "balanced_accuracy"


def baseline_features(
    episode: np.ndarray, episode_tasks: np.ndarray, baseline: str, bins: int = TIME_BINS
) -> np.ndarray:
    """float32 (rows, cells) one-hot of each row's baseline cell: its task (``task``), or its task and the
    decile of its normalised episode time (``task_time``, cell = task x bins + decile)."""
    episode = np.asarray(episode)
    task = np.asarray(episode_tasks)[episode]
    tasks = int(np.max(episode_tasks)) + 1 if len(episode_tasks) else 0
    if baseline == "task":
        cell, cells = task, tasks
    elif baseline == "task_time":
        cell, cells = task * bins + time_bin(episode, bins), tasks * bins
    else:
        raise ValueError(f"no conditional baseline {baseline!r}; use one of {CONDITIONAL_BASELINES}")
    out = np.zeros((len(episode), cells), np.float32)
    out[np.arange(len(episode)), cell] = 1.0
    return out


def combined_features(hidden: torch.Tensor, train_rows: np.ndarray, onehot: torch.Tensor) -> torch.Tensor:
    """(layers, steps, hidden + cells) float32: every row's hidden state standardised with the statistics of
    ``train_rows`` (per layer and feature, as the probes), then the baseline one-hot ``onehot`` (steps, cells)."""
    layers, steps, size = hidden.shape
    index = torch.as_tensor(np.asarray(train_rows), dtype=torch.long)
    out = torch.empty((layers, steps, size + onehot.shape[1]), dtype=torch.float32)
    for i in range(layers):
        h = hidden[i].to(torch.float32)
        train = h.index_select(0, index.to(h.device)).double()
        mean = train.mean(0).float()
        std = train.std(0, unbiased=False).clamp_min(1e-6).float()
        out[i, :, :size] = ((h - mean) / std).cpu()
        out[i, :, size:] = onehot
    return out


@dataclass
class ConditionalFit:
    """Held-out logits of one baseline's conditional probes, pooled over folds (rows: ``CrossFit.rows``)."""

    baseline: str
    features: torch.Tensor
    """(1, rows, atoms) logits of the probe on the baseline features alone."""
    combined: torch.Tensor
    """(layers, rows, atoms) logits of the probe on baseline features + hidden state."""
    c: np.ndarray
    """(layers, atoms) C of the combined probes' hidden-state block: the probes' own (the last fold's)."""


def conditional_fit(
    hidden: torch.Tensor,
    episode: np.ndarray,
    episode_tasks: np.ndarray,
    targets: np.ndarray,
    fold_rows: list[tuple[np.ndarray, np.ndarray]],
    cfg: TrainConfig,
    fold_probes: list[LinearProbes],
    defined: np.ndarray | None = None,
) -> dict[str, ConditionalFit]:
    """Fit and score the conditional probes of every baseline on each fold.

    ``fold_probes``: each fold's probes of ``targets`` (from :func:`~vlaprobe.probes.evaluate.cross_fit`). The
    combined probe penalises its hidden-state block with the C those probes chose at each layer and head and
    leaves the one-hot block unpenalised, as the features-only probe is: on a hidden state that adds nothing
    the two probes then coincide (gain 0), whatever C the probes needed. It starts from the fold's probe
    (hidden-state weights and bias; the one-hot weights at 0): the same minimiser, fewer iterations.
    ``defined`` (steps, atoms) bool, when given: both probes leave the undefined entries out (weight 0).
    """
    eval_rows = np.sort(np.concatenate([te for _, te in fold_rows]))
    probe_cfg = dataclasses.replace(cfg.probe, standardize=False)  # standardised here, one-hot kept 0/1
    layers, size, k, out = hidden.shape[0], hidden.shape[2], targets.shape[1], {}
    for name in CONDITIONAL_BASELINES:
        onehot = torch.as_tensor(baseline_features(episode, episode_tasks, name))
        cells = onehot.shape[1]
        free = torch.zeros(cells)
        penalized = torch.cat([torch.ones(size), free])
        features = torch.empty((1, len(eval_rows), k))
        combined = torch.empty((layers, len(eval_rows), k))
        c = np.zeros((layers, k))
        for (train_rows, test_rows), probes in zip(fold_rows, fold_probes, strict=True):
            at = np.searchsorted(eval_rows, test_rows)
            base = fit_probes(
                onehot[None], targets, train_rows, probe_cfg, 0, c=1.0, penalized=free, defined=defined
            )
            features[:, at] = base.logits(onehot[None], test_rows)
            assert probes.c is not None
            x = combined_features(hidden, train_rows, onehot)
            init = (torch.cat([probes.weight, torch.zeros((layers, cells, k))], 1), probes.bias)
            full = fit_probes(
                x,
                targets,
                train_rows,
                probe_cfg,
                0,
                c=probes.c,
                penalized=penalized,
                init=init,
                defined=defined,
            )
            combined[:, at] = full.logits(x, test_rows)
            c = probes.c
        out[name] = ConditionalFit(name, features, combined, c)
    return out


def evaluate_conditional(
    fit: ConditionalFit,
    cols: np.ndarray,
    truth: np.ndarray,
    row_groups: np.ndarray,
    num_groups: int,
    threshold_logit: float,
    weights: np.ndarray,
    atom_groups: list[np.ndarray],
    defined: np.ndarray | None = None,
) -> ConditionalProbe:
    """Balanced accuracy of one head's conditional probes (columns ``cols``; ``truth`` (rows, those atoms)),
    its intervals and the paired gain over the features-only probe, from the resamples ``weights``; ``defined``
    (rows, those atoms) leaves the undefined entries out."""
    metric = CONDITIONAL_METRIC

    def scored(logits: torch.Tensor) -> tuple[np.ndarray, np.ndarray]:
        point, res = atom_metrics(
            logits[:, :, cols], truth, row_groups, num_groups, threshold_logit, weights, 0, defined
        )
        return point[metric], res[metric]

    f_point, f_res = scored(fit.features)
    c_point, c_res = scored(fit.combined)
    gain = summarize(c_point - f_point, c_res - f_res, atom_groups)["layer"]
    return ConditionalProbe(
        baseline=fit.baseline,
        metric=metric,
        features=level(summarize(f_point, f_res, atom_groups)["layer"]),
        combined=level(summarize(c_point, c_res, atom_groups)["layer"]),
        gain=level(gain),
        c_features=None,
        c=[number(v) for v in fit.c[:, cols[0]]] if len(cols) else [],
    )


def adds_beyond(probe: ConditionalProbe) -> list[int]:
    """Positions of the layers whose gain's interval lies above 0 (the layer adds information beyond the
    baseline beyond its interval)."""
    low = probe.gain.low
    return [i for i, v in enumerate(low) if isinstance(v, (int, float)) and v > 0]
