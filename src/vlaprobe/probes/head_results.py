"""One label head's records in ``evaluation.json`` (:class:`HeadResult` and its parts), for
:mod:`vlaprobe.probes.results`, which holds the whole :class:`~vlaprobe.probes.results.Evaluation` and its file."""

from __future__ import annotations

from dataclasses import dataclass, field

from vlaprobe.files import Json

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
        """One of :data:`vlaprobe.probes.results.PARTS` by name (None when this run has no such part)."""
        return getattr(self, name)
