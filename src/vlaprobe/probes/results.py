"""The evaluation of a probe run (``evaluation.json``) as dataclasses, shared by its writer and its readers.

``vlaprobe train`` builds an :class:`Evaluation` and writes it with :func:`write_evaluation`; ``vlaprobe
report`` (and anything else) reads it with :func:`read_evaluation`. This module imports no torch. Arrays are
nested lists with ``None`` for undefined (NaN) values; :func:`arr` turns them back into float arrays.

Format version 2 (version 1 had none of these): every figure records in how many bootstrap resamples it was
defined (``defined``); the shuffled-label control is the mean of several permutations, with their spread
(``control_spread``); the split records the realized test fraction next to the requested one. Version 3:
the task and task x time baselines (``task_baseline``, ``task_time_baseline``) and the selectivity over the
latter (``selectivity_task_time``); how each probe was fit (``fit``: C per layer, cross-validation losses,
iterations, final loss and gradient norm per probe); averages keep a fixed set of atoms in every resample.
Version 4: the layers tied with the best one (``BestLayer.tied``; a version-3 file reads with the best layer
alone) and conditional probing over the task and task x time baselines (``conditional_task``,
``conditional_task_time``; absent from older files). Version 5: the atom families (``families``), the
matched-steps control (``matched``: a within-cell AUC per atom, family and layer, against the observer
control) and the conditional gain per family (``conditional_families``); absent (empty) in older files.
"""

from __future__ import annotations

import json
import math
from collections.abc import Mapping
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import SupportsFloat

import numpy as np

from vlaprobe.errors import VlaprobeError
from vlaprobe.files import Json, JsonObject, from_json, read_versioned, write_atomic

FORMAT = "vlaprobe-evaluation"
FORMAT_VERSION = 5
READABLE_VERSIONS = (3, 4, 5)
"""Format versions :func:`read_evaluation` accepts (older ones gain the new fields' defaults)."""
EVALUATION_FILE = "evaluation.json"
CONFIG_FILE = "config.json"
PARTS = (
    "probe",
    "baseline",
    "time_baseline",
    "task_baseline",
    "task_time_baseline",
    "control",
    "selectivity",
    "selectivity_time",
    "selectivity_task_time",
    "observer",
)
"""The metric summaries a head may have, in display order."""

Nested = list[Json]
"""A JSON array of any depth: floats, ints or None (NaN)."""


@dataclass
class Level:
    """One level of a metric summary: per atom (layers, atoms), per predicate (layers, predicates), per layer."""

    value: Nested
    """Point value on the held-out steps."""
    low: Nested
    """2.5th percentile over the bootstrap resamples (None where fewer than 2 resamples defined it)."""
    high: Nested
    """97.5th percentile, same."""
    defined: Nested
    """Resamples in which the figure was defined over all of its atoms (an atom: in which it was defined)."""
    count: Nested | None = None
    """Averages only: how many atoms were defined in the point value."""


@dataclass
class MetricSummary:
    """One metric at the three levels; intervals of averages come from the same resamples as the atoms'."""

    atom: Level
    predicate: Level
    layer: Level


@dataclass
class Spread:
    """Standard deviation over the shuffled-label permutations of their per-predicate and per-layer means."""

    predicate: Nested
    """(layers, predicates)."""
    layer: Nested
    """(layers,)."""


@dataclass
class BestLayer:
    """The head's best layer on the held-out data and the rule that chose it."""

    layer: int
    """Hidden-state index."""
    index: int
    """Position in the per-layer arrays."""
    metric: str
    value: float | None
    low: float | None
    high: float | None
    rule: str
    tied: list[int] = field(default_factory=list)
    """Hidden-state indices (ascending, the best included) of the layers statistically tied with the best:
    the paired bootstrap interval of (best minus layer) holds 0 (:mod:`vlaprobe.probes.ties`)."""
    tie_rule: str = ""


@dataclass
class ConditionalProbe:
    """Conditional probing (Hewitt et al. 2021) over one baseline: a probe on the baseline's features (one-hot
    cells, unpenalised) against one on those features plus the standardised hidden state (penalised with the
    probes' C at that layer), per layer, same split, solver and bootstrap resamples as the probes. The gain is
    the information the layer adds beyond the baseline."""

    baseline: str
    """``task`` or ``task_time`` (:data:`~vlaprobe.probes.baselines.BASELINES`)."""
    metric: str
    features: Level
    """(1,) the probe on the baseline features alone (it does not depend on the layer)."""
    combined: Level
    """(layers,) the probe on the baseline features and the layer's standardised hidden state."""
    gain: Level
    """(layers,) combined minus features, per resample (paired)."""
    c_features: float | None
    """None: the cells are unpenalised (files written before that hold the C a search chose for them)."""
    c: Nested
    """(layers,) C of the combined probes' hidden-state block: the probes' (the last fold's)."""


@dataclass
class MatchedPairs:
    """The matched-steps control (:mod:`vlaprobe.probes.matched`): per atom, among pairs of held-out steps in
    the same task x time cell with different values of the atom, the share the probe's logit ranks correctly
    (ties 0.5), an AUC within cells; 0.5 is chance. Undefined (None) for atoms without such a pair."""

    metric: str
    cells: str
    """The rule that makes the pairs."""
    pairs: Nested
    """(atoms,) matched pairs per atom (the same at every layer)."""
    probe: MetricSummary
    """Per atom, per predicate and per layer (mean over the atoms with pairs)."""
    family: Level
    """(layers, families) the mean over each family's atoms (:attr:`HeadResult.families` order)."""
    observer: MetricSummary | None = None
    """The same statistic of the probes on the observer control's hidden states."""
    observer_family: Level | None = None
    difference: MetricSummary | None = None
    """Probe minus observer, per resample (paired when the observer saw the same episodes)."""
    difference_family: Level | None = None
    paired: bool = False
    """The difference's resamples draw the same test episodes for both observers."""


@dataclass
class DroppedAtom:
    """An atom not probed: too rare or too common in a training split."""

    atom: str
    train_frequency: float
    reason: str


@dataclass
class ProbeFit:
    """How the head's probes were fit: regularisation chosen and where the solver stopped, per probe."""

    tol: float
    """Stopping tolerance on the largest absolute gradient entry."""
    max_iter: int
    standardized: bool
    c: Nested
    """(layers,) the inverse L2 strength C used per layer."""
    c_grid: list[float]
    cv_folds: int
    """Folds of the cross-validation over training episodes that chose C (0: C was not cross-validated)."""
    cv_loss: Nested | None
    """(layers, grid) mean held-out log-loss of each C, or None."""
    iterations: Nested
    """(layers, atoms) L-BFGS iterations."""
    loss: Nested
    """(layers, atoms) final objective."""
    grad_norm: Nested
    """(layers, atoms) final largest absolute gradient entry."""
    at_cap: int
    """Probes that stopped at ``max_iter`` without reaching ``tol``."""
    probes: int
    """Probes fit (layers x atoms)."""
    stalled: int = 0
    """Probes that stopped above ``tol`` before the cap, where no step lowered the objective (float32
    round-off near the minimum)."""
    cv_score: Nested | None = None
    """(layers, grid) mean held-out balanced accuracy of each C (the selection criterion), or None."""
    c_rule: str = ""
    """How C was chosen from ``cv_score``."""
    c_at_edge: list[bool] | None = None
    """(layers,) the chosen C is the grid's smallest or largest: the best C may lie outside the grid (None:
    not recorded, C not cross-validated)."""

    def edge_warning(self, head: str) -> str | None:
        """One line when the chosen C sits at an end of the grid at some layer, or when a grid was given and
        could not be searched, else None."""
        if self.c_at_edge is None and len(self.c_grid) > 1 and self.c_rule.startswith("C = "):
            return (
                f"{head}: {self.c_rule}; C is searched where a task has at least 2 training episodes "
                "(3 episodes per task with the default --split.test-fraction)"
            )
        if not self.c_at_edge or not any(self.c_at_edge):
            return None
        edge = [i for i, e in enumerate(self.c_at_edge) if e]
        values = sorted({float(self.c[i]) for i in edge if isinstance(self.c[i], (int, float))})
        return (
            f"{head}: C at the edge of its grid ({min(self.c_grid):g} to {max(self.c_grid):g}) at "
            f"{len(edge)} of {len(self.c_at_edge)} layers (C = {', '.join(f'{v:g}' for v in values)}): "
            "the best C may lie outside the grid; widen --probe.c-grid"
        )


@dataclass
class HeadResult:
    """Everything measured for one label head ("object" or "action")."""

    atoms: list[str]
    """Probed atoms (the columns of every per-atom array)."""
    predicates: list[str]
    """Predicates with at least one probed atom, in the paper's figure order."""
    predicate_atoms: dict[str, list[str]]
    skipped_predicates: list[str]
    """Predicates whose atoms were all dropped."""
    dropped: list[DroppedAtom]
    train_frequency: Nested
    test_frequency: Nested
    best: BestLayer
    probe: dict[str, MetricSummary]
    """Metric name -> summary of the probes."""
    baseline: dict[str, MetricSummary]
    """The majority-class baseline (one row: it does not depend on the layer)."""
    time_baseline: dict[str, MetricSummary] | None = None
    """Decile of normalised episode time -> per-atom training majority over all tasks (one row): the comparator
    of held-out tasks (absent from older files)."""
    selectivity_time: dict[str, MetricSummary] | None = None
    """Probe minus the time baseline, per resample (paired)."""
    task_baseline: dict[str, MetricSummary] | None = None
    """Task -> per-atom training majority (one row)."""
    task_time_baseline: dict[str, MetricSummary] | None = None
    """(Task, decile of normalised episode time) -> per-atom training majority (one row)."""
    selectivity_task_time: dict[str, MetricSummary] | None = None
    """Probe minus the task x time baseline, per resample (paired)."""
    fit: ProbeFit | None = None
    """How the probes evaluated here were fit."""
    control: dict[str, MetricSummary] | None = None
    """The shuffled-label control: mean over the permutations (point and resamples)."""
    control_spread: dict[str, Spread] | None = None
    """Standard deviation of the control over its permutations."""
    selectivity: dict[str, MetricSummary] | None = None
    """Probe minus the control's mean, per resample."""
    observer: dict[str, MetricSummary] | None = None
    """The same probes trained on a second observer's hidden states."""
    observer_best: BestLayer | None = None
    conditional_task: ConditionalProbe | None = None
    """Conditional probing over the task baseline (None when not computed)."""
    conditional_task_time: ConditionalProbe | None = None
    """Conditional probing over the task x time baseline (None when not computed)."""
    families: dict[str, list[str]] = field(default_factory=dict)
    """Atom family (:mod:`vlaprobe.probes.families`) -> its probed atoms, for the per-family figures."""
    matched: MatchedPairs | None = None
    """The matched-steps control (None in files before version 5)."""
    conditional_families: dict[str, Level] = field(default_factory=dict)
    """Baseline -> (layers, families) the conditional gain per family (:attr:`families` order)."""

    def conditional(self) -> dict[str, ConditionalProbe]:
        """Baseline name -> its conditional probing, for the baselines this run has."""
        parts = {"task": self.conditional_task, "task_time": self.conditional_task_time}
        return {k: v for k, v in parts.items() if v is not None}

    def part(self, name: str) -> dict[str, MetricSummary] | None:
        """One of :data:`PARTS` by name (None when this run has no such part)."""
        return getattr(self, name)


@dataclass
class SkippedHead:
    reason: str
    dropped: list[DroppedAtom]


@dataclass
class Episodes:
    episodes: int
    steps: int


@dataclass
class Split:
    unit: str
    stratified_by: str
    folds: int
    test_fraction: float
    """The requested share of episodes held out (1/folds for k-fold)."""
    realized_test_fraction: float
    """The share actually held out: test episodes / all episodes (per fold for k-fold), after rounding."""
    train: Episodes
    test: Episodes
    test_episodes: list[str]
    leak_check: str


@dataclass
class Dataset:
    episodes: int
    steps: int
    episodes_per_task: dict[str, int]


@dataclass
class Bootstrap:
    unit: str
    interval: str
    resamples: int
    auprc_resamples: int
    undefined: str
    """How resamples in which a figure is undefined are treated."""


@dataclass
class ObserverInfo:
    model_id: str
    pooling: str
    layers: list[int]
    same_episodes: bool
    steps: int
    episodes: int


@dataclass
class Controls:
    shuffled_labels: bool
    shuffled_permutations: int
    """Label permutations trained for the shuffled-label control (0 without it)."""
    observer: ObserverInfo | None = None


@dataclass
class Evaluation:
    """The content of ``evaluation.json``."""

    model_id: str
    pooling: str
    layers: list[int]
    hidden_size: int
    threshold: float
    metrics: list[str]
    dataset: Dataset
    split: Split
    bootstrap: Bootstrap
    controls: Controls
    heads: dict[str, HeadResult]
    config: JsonObject
    seeds: dict[str, int]
    versions: dict[str, str | None]
    skipped_heads: dict[str, SkippedHead] = field(default_factory=dict)
    seconds: dict[str, float] = field(default_factory=dict)
    suite: str = "libero_spatial"
    """The LIBERO suite of the episodes (files without it: LIBERO-spatial's)."""
    format: str = FORMAT
    format_version: int = FORMAT_VERSION


# -- conversions -------------------------------------------------------------------------------------------


DECIMALS = 10
"""Decimals kept in the file: enough that a figure quoted at 3 decimals rounds once, from the computed value
(at 5, 0.738496 was stored as 0.7385 and quoted as 0.739 where ``vlaprobe hypotheses`` printed 0.738), and
few enough to drop the float noise of the last bits."""


def nested(x: object) -> Nested:
    """A float array as nested lists, NaN -> None, rounded to :data:`DECIMALS` (ints and bools as they are)."""
    a = np.asarray(x)
    if a.dtype.kind in "iub":
        return a.tolist()
    rounded = np.round(a.astype(np.float64), DECIMALS)
    return np.where(np.isnan(rounded), np.array(None), rounded).tolist()


def level(x: Mapping[str, np.ndarray]) -> Level:
    """A :class:`Level` from one level of :func:`~vlaprobe.probes.metrics.summarize`'s output."""
    count = nested(x["count"]) if "count" in x else None
    return Level(nested(x["value"]), nested(x["low"]), nested(x["high"]), nested(x["defined"]), count)


def number(x: SupportsFloat) -> float | None:
    """One float rounded to :data:`DECIMALS`, NaN -> None."""
    x = float(x)
    return None if math.isnan(x) else round(x, DECIMALS)


def arr(x: Nested | None) -> np.ndarray:
    """Nested lists back to a float array (None -> NaN)."""
    return np.array(x, dtype=float)


def write_evaluation(folder: Path, evaluation: Evaluation) -> Path:
    """Write ``evaluation.json`` atomically; return its path."""
    path = Path(folder) / EVALUATION_FILE
    write_atomic(path, json.dumps(asdict(evaluation), allow_nan=False) + "\n")
    return path


def read_evaluation(folder: str | Path) -> Evaluation:
    """Read ``<folder>/evaluation.json``; a one-line error if it is missing, damaged or of another version."""
    path = Path(folder) / EVALUATION_FILE
    if Path(folder).is_file():
        raise VlaprobeError(
            f"{folder} is a file, not a probe folder; pass the folder written by vlaprobe train"
        )
    if not path.is_file():
        raise VlaprobeError(
            f"no {EVALUATION_FILE} in {folder}; pass the folder written by vlaprobe train (--probes)"
        )
    hint = "run vlaprobe train again"
    data, _ = read_versioned(path, FORMAT, "evaluation", READABLE_VERSIONS, hint)
    evaluation = from_json(Evaluation, data, path, hint)
    for head in evaluation.heads.values():
        for best in (head.best, head.observer_best):
            if best is not None and not best.tied:  # version 3: the best layer is the whole set
                best.tied = [best.layer]
    return evaluation


def read_test_episodes(folder: str | Path) -> list[str]:
    """The held-out test episodes of ``<folder>/evaluation.json`` (read with :func:`read_evaluation`)."""
    return list(read_evaluation(folder).split.test_episodes)
