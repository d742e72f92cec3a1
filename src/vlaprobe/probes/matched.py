"""The matched-steps control, and the conditional gain per atom family: what a probe reads beyond task and time.

On expert episodes the task and the elapsed time predict most atoms, so a probe can score well by reading the
clock. The matched-steps control (after Zhang et al. 2026, "What frozen VLAs already know about success")
compares only steps the clock cannot tell apart: pairs of held-out steps of the same task and the same decile
of normalised episode time (the cells of the task x time baseline, :func:`~vlaprobe.probes.baselines.
task_time_cell`) where an atom holds at one and not at the other. Per atom and layer the figure is the share of
such pairs whose positive step gets the higher probe logit, ties counting one half: an AUC within cells, 0.5
for a probe that knows nothing beyond the cell. The per-predicate, per-family and per-layer figures are means
over atoms (:func:`~vlaprobe.probes.metrics.summarize`).

Intervals come from the episode bootstrap (:mod:`vlaprobe.probes.bootstrap`): a pair counts as often as the
product of its two steps' episode multiplicities, so the counts are kept per pair of test episodes (positive
step's, negative step's) and a resample's AUC is ``w' C w / w' N w``. The same resamples score the observer
control, so the difference is paired when both observers saw the same episodes.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch

from vlaprobe.probes.baselines import task_time_cell
from vlaprobe.probes.conditional import CONDITIONAL_METRIC
from vlaprobe.probes.data import ProbeData
from vlaprobe.probes.evaluate import CrossFit
from vlaprobe.probes.families import family_columns
from vlaprobe.probes.metrics import atom_metrics, summarize
from vlaprobe.probes.results import HeadResult, Level, MatchedPairs, MetricSummary, level, nested

MATCHED_METRIC = "matched_auc"
CELLS = (
    "pairs of held-out steps of the same task and decile of normalised episode time with different values "
    "of the atom; the share whose true step has the higher logit (ties 1/2)"
)


def pair_counts(
    scores: torch.Tensor,
    truth: np.ndarray,
    cells: np.ndarray,
    groups: np.ndarray,
    num_groups: int,
    budget: int = 4_000_000,
    defined: np.ndarray | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """Correctly ranked pairs (layers, atoms, G, G) and all pairs (atoms, G, G), per (positive step's group,
    negative step's group), summed over cells.

    ``scores`` (layers, rows, atoms), ``truth`` bool (rows, atoms), ``cells`` and ``groups`` int (rows,).
    A pair is two rows of one cell, the atom true at the first and false at the second; it is ranked
    correctly when the first scores higher (a tie counts 1/2). Atoms are taken in chunks of at most ``budget``
    (layers x rows x rows) entries per cell. ``defined`` (rows, atoms) bool, when given: an undefined entry is
    in no pair."""
    scores = torch.as_tensor(scores)
    truth = np.asarray(truth, bool)
    known = np.ones_like(truth) if defined is None else np.asarray(defined, bool)
    positive, negative = truth & known, ~truth & known
    layers, atoms = scores.shape[0], truth.shape[1]
    correct = np.zeros((layers, atoms, num_groups, num_groups))
    pairs = np.zeros((atoms, num_groups, num_groups))
    for cell in np.unique(cells):
        rows = np.flatnonzero(cells == cell)
        y, n = positive[rows], negative[rows]
        vary = np.flatnonzero(y.any(0) & n.any(0))
        if not len(vary):
            continue
        onehot = np.eye(num_groups)[np.asarray(groups)[rows]]  # (n, G)
        pairs[vary] += np.einsum("ga,ha->agh", onehot.T @ y[:, vary], onehot.T @ n[:, vary])
        e = torch.as_tensor(onehot)
        s = scores[:, torch.as_tensor(rows)]
        step = max(1, budget // (layers * len(rows) ** 2))
        for start in range(0, len(vary), step):
            chunk = vary[start : start + step]
            sc = s[:, :, torch.as_tensor(chunk)].double()
            yc, nc = torch.as_tensor(y[:, chunk]), torch.as_tensor(n[:, chunk])
            diff = sc[:, :, None, :] - sc[:, None, :, :]  # (layers, i, j, chunk): score of i minus j
            win = (diff > 0).double() + 0.5 * (diff == 0).double()
            win *= (yc[:, None, :] & nc[None, :, :]).double()  # i true, j false
            correct[:, chunk] += torch.einsum("lijc,ig,jh->lcgh", win, e, e).numpy()
    return correct, pairs


def matched_auc(correct: np.ndarray, pairs: np.ndarray, weights: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Point values (layers, atoms) and resamples (resamples, layers, atoms) of the AUC within cells, from
    :func:`pair_counts` and (resamples, groups) episode multiplicities; NaN where there is no pair."""
    layers, atoms, g, _ = correct.shape
    total = pairs.sum((1, 2))
    with np.errstate(invalid="ignore", divide="ignore"):
        point = np.where(total > 0, correct.sum((2, 3)) / total, np.nan)
    w = np.asarray(weights, np.float64)
    ww = (w[:, :, None] * w[:, None, :]).reshape(len(w), g * g)  # a pair's multiplicity, per resample
    num = (ww @ correct.reshape(layers * atoms, g * g).T).reshape(len(w), layers, atoms)
    den = ww @ pairs.reshape(atoms, g * g).T  # (resamples, atoms)
    with np.errstate(invalid="ignore", divide="ignore"):
        resampled = np.where(den[:, None] > 0, num / den[:, None], np.nan)
    return point, resampled


@dataclass
class Scored:
    """One observer's held-out probe scores and what the within-cell figures need besides."""

    data: ProbeData
    fitted: CrossFit
    targets: np.ndarray
    """(steps, columns) the probed atoms of every head."""
    weights: np.ndarray
    """(resamples, test episodes) the bootstrap's multiplicities."""

    def matched(self, cols: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """:func:`matched_auc` of the atoms in columns ``cols``, and their numbers of pairs (atoms,)."""
        f = self.fitted
        cells = task_time_cell(self.data.episode, self.data.episode_tasks)[f.rows]
        truth = self.targets[f.rows][:, cols]
        held = None if f.defined is None else f.defined[:, cols]
        correct, pairs = pair_counts(f.logits[:, :, cols], truth, cells, f.groups, f.num_groups, defined=held)
        return (*matched_auc(correct, pairs, self.weights), pairs.sum((1, 2)))


def _summary(point: np.ndarray, resampled: np.ndarray, groups: list[np.ndarray]) -> MetricSummary:
    return MetricSummary(**{k: level(v) for k, v in summarize(point, resampled, groups).items()})


def _family(point: np.ndarray, resampled: np.ndarray, families: list[np.ndarray]) -> Level:
    return level(summarize(point, resampled, families)["predicate"])


def conditional_family_gain(
    main: Scored, cols: np.ndarray, threshold_logit: float, families: list[np.ndarray]
) -> dict[str, Level]:
    """Baseline -> (layers, families) the conditional probes' gain (combined minus features-only balanced
    accuracy, paired per resample) averaged per family, from the held-out logits of
    :func:`~vlaprobe.probes.conditional.conditional_fit`."""
    f = main.fitted
    truth = main.targets[f.rows][:, cols]
    held = None if f.defined is None else f.defined[:, cols]

    def scored(logits: torch.Tensor) -> tuple[np.ndarray, np.ndarray]:
        point, res = atom_metrics(
            logits[:, :, cols], truth, f.groups, f.num_groups, threshold_logit, main.weights, 0, held
        )
        return point[CONDITIONAL_METRIC], res[CONDITIONAL_METRIC]

    out = {}
    for name, cf in f.conditional.items():
        (f_point, f_res), (c_point, c_res) = scored(cf.features), scored(cf.combined)
        out[name] = _family(c_point - f_point, c_res - f_res, families)
    return out


def _against_observer(
    matched: MatchedPairs,
    observer: Scored,
    main: Scored,
    cols: np.ndarray,
    probe: tuple[np.ndarray, np.ndarray],
    groups: list[np.ndarray],
    families: list[np.ndarray],
) -> None:
    """The observer control's matched-steps figures and the probes' difference from them (when both have the
    same layers)."""
    (point, res), (o_point, o_res, _) = probe, observer.matched(cols)
    matched.observer = _summary(o_point, o_res, groups)
    matched.observer_family = _family(o_point, o_res, families)
    if o_res.shape == res.shape:
        matched.difference = _summary(point - o_point, res - o_res, groups)
        matched.difference_family = _family(point - o_point, res - o_res, families)
        matched.paired = observer.data.episode_keys == main.data.episode_keys


def add_within_cells(
    head_results: dict[str, HeadResult],
    main: Scored,
    columns: dict[str, np.ndarray],
    threshold_logit: float,
    observer: Scored | None = None,
) -> None:
    """Set each head's families, matched-steps control (against ``observer`` when given) and conditional gain
    per family."""
    for head, result in head_results.items():
        cols = columns[head]
        by_family = family_columns(result.atoms)
        families = list(by_family.values())
        result.families = {name: [result.atoms[i] for i in c] for name, c in by_family.items()}
        at = {a: i for i, a in enumerate(result.atoms)}
        groups = [np.array([at[a] for a in result.predicate_atoms[p]]) for p in result.predicates]
        point, res, pairs = main.matched(cols)
        result.matched = MatchedPairs(
            metric=MATCHED_METRIC,
            cells=CELLS,
            pairs=nested(pairs.astype(np.int64)),
            probe=_summary(point, res, groups),
            family=_family(point, res, families),
        )
        if observer is not None:
            _against_observer(result.matched, observer, main, cols, (point, res), groups, families)
        result.conditional_families = conditional_family_gain(main, cols, threshold_logit, families)
