"""A run's headline figures (``<run>/results.json``): the one file the README and docs quote figures from.

``vlaprobe run`` builds a :class:`RunResults` from the run's typed readers (the probes' evaluation, the
cognition's figures) and writes it with :func:`write_results`; :func:`read_results` reads it back
(``scripts/publish_results.py`` copies one into ``docs/results/``, ``tests/test_docs_figures.py`` checks the
figures the docs quote against it). Figures are flat, dot-separated keys (``object.best.value``); an interval
adds ``.value``, ``.low`` and ``.high``. A new figure is one line in :data:`HEAD_FIGURES`,
:data:`COGNITION_FIGURES` or :data:`RUN_FIGURES`.

Format version 1.
"""

from __future__ import annotations

import json
from collections.abc import Callable, Mapping
from dataclasses import asdict, dataclass
from pathlib import Path

import dacite

from vlaprobe.cognition.monitor import MONITOR_FILE, MonitorResult, read_monitor
from vlaprobe.errors import VlaprobeError
from vlaprobe.files import from_json, read_versioned, write_atomic
from vlaprobe.probes.results import Evaluation, HeadResult, MetricSummary, read_evaluation

FORMAT = "vlaprobe-results"
FORMAT_VERSION = 1
RESULTS_FILE = "results.json"

Number = float | int | None
"""One figure: None where the run left it undefined."""


@dataclass(frozen=True)
class Interval:
    """A figure with its 95% bootstrap interval (stored as ``<key>.value``, ``<key>.low``, ``<key>.high``)."""

    value: float | None
    low: float | None
    high: float | None


Figure = Interval | Number


UNDEFINED = Interval(None, None, None)


def _layer_row(part: Mapping[str, MetricSummary] | None, metric: str, index: int) -> Interval:
    """The mean-over-atoms figure of ``part`` at position ``index`` of its per-layer arrays."""
    if part is None or metric not in part:
        return UNDEFINED
    level = part[metric].layer
    return Interval(level.value[index], level.low[index], level.high[index])


def _at_best(h: HeadResult, part: str) -> Interval:
    """``part`` at the head's best layer (a baseline has one row for every layer)."""
    index = 0 if part.endswith("baseline") else h.best.index
    return _layer_row(h.part(part), h.best.metric, index)


def _control_best(h: HeadResult) -> Interval:
    b = h.observer_best
    return UNDEFINED if b is None else Interval(b.value, b.low, b.high)


def _tied(h: HeadResult) -> list[int]:
    return h.best.tied or [h.best.layer]


def _max_gain_index(h: HeadResult, baseline: str) -> int | None:
    """Position of the layer with the largest conditional-probing gain over ``baseline`` (None: not fit)."""
    c = h.conditional().get(baseline)
    values = [] if c is None else [(v, i) for i, v in enumerate(c.gain.value) if isinstance(v, (int, float))]
    return max(values)[1] if values else None


def _gain_at(h: HeadResult, layers: list[int], baseline: str, field: str) -> Figure:
    """The largest gain of conditional probing over ``baseline`` (``gain``: with its interval; ``layer``: where;
    ``features``: the baseline-features probe alone; ``layers_above``: layers whose gain interval is above 0)."""
    c, i = h.conditional().get(baseline), _max_gain_index(h, baseline)
    if c is None or i is None:
        return UNDEFINED if field == "gain" else None
    if field == "gain":
        return Interval(c.gain.value[i], c.gain.low[i], c.gain.high[i])
    if field == "layer":
        return layers[i]
    if field == "features":
        v = c.features.value[0]
        return v if isinstance(v, (int, float)) else None
    return sum(isinstance(low, (int, float)) and low > 0 for low in c.gain.low)


HEAD_FIGURES: dict[str, Callable[[HeadResult], Figure]] = {
    "atoms": lambda h: len(h.atoms),
    "best.layer": lambda h: h.best.layer,
    "best": lambda h: Interval(h.best.value, h.best.low, h.best.high),
    "majority": lambda h: _at_best(h, "baseline"),
    "time_baseline": lambda h: _at_best(h, "time_baseline"),
    "task_baseline": lambda h: _at_best(h, "task_baseline"),
    "task_time_baseline": lambda h: _at_best(h, "task_time_baseline"),
    "shuffled": lambda h: _at_best(h, "control"),
    "selectivity": lambda h: _at_best(h, "selectivity"),
    "selectivity_time": lambda h: _at_best(h, "selectivity_time"),
    "selectivity_task_time": lambda h: _at_best(h, "selectivity_task_time"),
    "control.best.layer": lambda h: None if h.observer_best is None else h.observer_best.layer,
    "control.best": _control_best,
    "tied.count": lambda h: len(_tied(h)),
    "tied.first": lambda h: min(_tied(h)),
    "tied.last": lambda h: max(_tied(h)),
}
"""Per head (``<head>.<key>``): figures of ``evaluation.json`` at the head's best layer. ``control`` is the
control observer (the untrained network), ``shuffled`` the shuffled-label control; ``tied`` the layers
statistically tied with the best (``tied.first`` is the default layer)."""


def _conditional_figure(baseline: str, field: str) -> Callable[[HeadResult, list[int]], Figure]:
    return lambda h, layers: _gain_at(h, layers, baseline, field)


HEAD_LAYER_FIGURES: dict[str, Callable[[HeadResult, list[int]], Figure]] = {
    f"conditional_{b}.{f}": _conditional_figure(b, f)
    for b in ("task", "task_time")
    for f in ("gain", "layer", "features", "layers_above")
}
"""Per head: conditional probing over the task and task x time baselines, at the layer of the largest gain."""


def _detected(m: MonitorResult) -> int:
    return sum(e.goal_step_truth is not None and e.goal_step_probes is not None for e in m.per_episode)


def _gain(m: MonitorResult) -> Interval:
    g = m.probes.belief_agreement_gain_95
    value = m.probes.belief_agreement - m.probes.belief_agreement_step0
    return Interval(value, None if g is None else g[0], None if g is None else g[1])


COGNITION_FIGURES: dict[str, Callable[[MonitorResult], Figure]] = {
    "episodes": lambda m: m.episodes,
    "goal.detected": _detected,
    "goal.recall": lambda m: m.probes.goal_detection.recall,
    "goal.precision": lambda m: m.probes.goal_detection.precision,
    "goal.false_alarms_per_100_steps": lambda m: m.probes.goal_detection.false_alarms_per_100_steps,
    "goal.mean_delay_steps": lambda m: m.probes.goal_detection.mean_delay_steps,
    "goal.failed_episodes": lambda m: m.probes.goal_detection.failed_episodes,
    "subgoal_accuracy": lambda m: m.probes.subgoal_accuracy,
    "violations_per_100_steps": lambda m: m.probes.violations_per_100_steps,
    "truth_violations_per_100_steps": lambda m: m.truth.violations_per_100_steps,
    "flips_per_step": lambda m: m.probes.flips_per_step,
    "flips_per_step_debounced": lambda m: m.probes.flips_per_step_debounced,
    "belief_agreement": lambda m: m.probes.belief_agreement,
    "belief_agreement_step0": lambda m: m.probes.belief_agreement_step0,
    "belief_agreement_gain": _gain,
}
"""The cognition over the held-out episodes (``cognition.<key>``), from the monitor's figures."""

RUN_FIGURES: dict[str, Callable[[Evaluation], Figure]] = {
    "layers": lambda e: len(e.layers),
    "episodes": lambda e: e.dataset.episodes,
    "steps": lambda e: e.dataset.steps,
    "train_episodes": lambda e: e.split.train.episodes,
    # every episode whose held-out steps the figures pool (all of them under k-fold or leave-one-task-out),
    # not one fold's share: the intervals resample these
    "test_episodes": lambda e: len(e.split.test_episodes),
}
"""The run as a whole (``run.<key>``)."""


@dataclass
class RunResults:
    """The content of ``results.json``."""

    model_id: str
    """The observer whose hidden states were probed."""
    control_model_id: str | None
    """The control observer (None: the run had none)."""
    vlaprobe_version: str
    figures: dict[str, Number]
    """Flat key -> figure (None: undefined in this run)."""
    suite: str = "libero_spatial"
    """The LIBERO suite of the run's episodes."""
    format: str = FORMAT
    format_version: int = FORMAT_VERSION

    def figure(self, key: str) -> Number:
        """One figure by key; a one-line error naming the known keys' prefixes when there is no such key."""
        if key not in self.figures:
            roots = sorted({k.rsplit(".", 1)[0] for k in self.figures})
            raise VlaprobeError(
                f"no figure {key!r} in the results; known: {', '.join(roots)} (+ .value/.low/.high)"
            )
        return self.figures[key]


def _put(figures: dict[str, Number], key: str, figure: Figure) -> None:
    if isinstance(figure, Interval):
        for name, v in asdict(figure).items():
            figures[f"{key}.{name}"] = v
    else:
        figures[key] = figure


def build_results(evaluation: Evaluation, cognition: MonitorResult | None) -> RunResults:
    """The headline figures of one run from its evaluation and (when it ran) the cognition's figures."""
    figures: dict[str, Number] = {}
    for key, of_run in RUN_FIGURES.items():
        _put(figures, f"run.{key}", of_run(evaluation))
    for head, h in evaluation.heads.items():
        for key, of_head in HEAD_FIGURES.items():
            _put(figures, f"{head}.{key}", of_head(h))
        for key, of_head_layers in HEAD_LAYER_FIGURES.items():
            _put(figures, f"{head}.{key}", of_head_layers(h, evaluation.layers))
    if cognition is not None:
        for key, of_cognition in COGNITION_FIGURES.items():
            _put(figures, f"cognition.{key}", of_cognition(cognition))
    observer = evaluation.controls.observer
    return RunResults(
        suite=evaluation.suite,
        model_id=evaluation.model_id,
        control_model_id=None if observer is None else observer.model_id,
        vlaprobe_version=evaluation.versions.get("vlaprobe") or "unknown",
        figures=figures,
    )


def write_results(folder: str | Path, results: RunResults, name: str = RESULTS_FILE) -> Path:
    """Write ``<folder>/<name>`` (default ``results.json``) atomically; return its path."""
    path = Path(folder) / name
    write_atomic(path, json.dumps(asdict(results), indent=1, allow_nan=False) + "\n")
    return path


def read_results(path: str | Path) -> RunResults:
    """Read a results file (or ``<folder>/results.json``); a one-line error if it is missing, damaged or of
    another version."""
    path = Path(path)
    if path.is_dir():
        path = path / RESULTS_FILE
    hint = "pass a run folder written by vlaprobe run (run it again), or its results.json"
    data, _ = read_versioned(path, FORMAT, "results file", (FORMAT_VERSION,), hint)
    return from_json(RunResults, data, path, hint, dacite.Config(strict=True))


def _read_cognition(probes: Path) -> MonitorResult | None:
    """The cognition's figures from ``<probes>/monitor.json`` (None: the run has none)."""
    return read_monitor(probes) if (probes / MONITOR_FILE).is_file() else None


def results_from_run(run: str | Path) -> RunResults:
    """The results of a run folder from its files (``probes/evaluation.json``, ``probes/monitor.json``): for
    a run written before ``results.json`` existed."""
    probes = Path(run) / "probes"
    return build_results(read_evaluation(probes), _read_cognition(probes))
