"""The observer against the control observer, layer by layer: a section of the report.

``vlaprobe run`` trains the probes of its observer (the trained tiny model by default) with the random tiny
network as the observer control of ``vlaprobe train``: the same episodes, split and bootstrap resamples, so
the two per-layer curves compare directly. A layer is **better than the control** when the lower end of the
observer's 95% interval lies above the upper end of the control's (the intervals do not overlap: a
conservative test), and **worse** in the mirror case.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

from vlaprobe.probes.results import EVALUATION_FILE, Evaluation, MetricSummary, read_evaluation

SECTION_ID = "observer-vs-control"
SECTION_TITLE = "Observer versus control observer"
SECTION_TEMPLATE = "compare_section.html"
METRIC = "balanced_accuracy"
"""The metric compared: the mean over a head's probed atoms of the per-atom balanced accuracy."""


@dataclass
class LayerRow:
    """One hidden state: the observer's and the control's mean figure with their 95% intervals."""

    layer: int
    observer: float | None
    observer_low: float | None
    observer_high: float | None
    control: float | None
    control_low: float | None
    control_high: float | None
    verdict: str
    """"better", "worse" or "" (the intervals overlap, or a figure is undefined)."""


@dataclass
class HeadComparison:
    head: str
    rows: list[LayerRow]
    better: list[int]
    """Layers better than the control beyond the intervals."""
    worse: list[int]
    best_observer: LayerRow
    """The observer's best layer by point value (on the test episodes)."""
    best_control: LayerRow


@dataclass
class Comparison:
    """What the section shows."""

    observer: str
    control: str
    metric: str
    heads: list[HeadComparison]


def _verdict(row: LayerRow) -> str:
    lo, hi, c_lo, c_hi = row.observer_low, row.observer_high, row.control_low, row.control_high
    if lo is not None and c_hi is not None and lo > c_hi:
        return "better"
    if hi is not None and c_lo is not None and hi < c_lo:
        return "worse"
    return ""


def compare_head(
    head: str, layers: list[int], observer: MetricSummary, control: MetricSummary
) -> HeadComparison:
    """Per-layer rows of two summaries of the same metric (``MetricSummary.layer``: value, low, high)."""
    o, c = observer.layer, control.layer
    rows = []
    for i, layer in enumerate(layers):
        row = LayerRow(layer, o.value[i], o.low[i], o.high[i], c.value[i], c.low[i], c.high[i], "")
        row.verdict = _verdict(row)
        rows.append(row)

    def best(values: list[float | None]) -> LayerRow:
        scored = [(v, -i) for i, v in enumerate(values) if v is not None]
        return rows[-max(scored)[1]] if scored else rows[0]

    return HeadComparison(
        head=head,
        rows=rows,
        better=[r.layer for r in rows if r.verdict == "better"],
        worse=[r.layer for r in rows if r.verdict == "worse"],
        best_observer=best([r.observer for r in rows]),
        best_control=best([r.control for r in rows]),
    )


def compare(evaluation: Evaluation, metric: str = METRIC) -> Comparison | None:
    """The comparison of an evaluation that has an observer control; None without one."""
    info = evaluation.controls.observer
    if info is None:
        return None
    heads = [
        compare_head(name, evaluation.layers, h.probe[metric], h.observer[metric])
        for name, h in evaluation.heads.items()
        if h.observer is not None and metric in h.probe and metric in h.observer
    ]
    return Comparison(observer=evaluation.model_id, control=info.model_id, metric=metric, heads=heads)


def report_section(probes: Path) -> object | None:
    """Section provider (``vlaprobe.reports.sections``): the comparison when the probe folder's evaluation has
    an observer control, else None."""
    from vlaprobe.reports.sections import Section

    if not (Path(probes) / EVALUATION_FILE).is_file():
        return None
    comparison = compare(read_evaluation(probes))
    if comparison is None:
        return None
    return Section(id=SECTION_ID, title=SECTION_TITLE, template=SECTION_TEMPLATE, data=comparison)
