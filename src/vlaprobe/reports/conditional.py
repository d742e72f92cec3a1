"""The report's conditional-probing section: what the hidden states add beyond task and time.

Reads each head's ``conditional_task`` / ``conditional_task_time`` of ``evaluation.json``
(:mod:`vlaprobe.probes.conditional`): per layer, the balanced accuracy of the probe on the baseline's
one-hot cells alone, on those cells plus the standardised hidden state, and the paired gain with its 95 %
interval; one sentence per head says whether any layer adds information beyond task x time beyond its
interval (the gain's lower end above 0).
"""

from __future__ import annotations

from vlaprobe.files import Json, JsonObject
from vlaprobe.probes.conditional import adds_beyond
from vlaprobe.probes.results import ConditionalProbe, Evaluation, HeadResult
from vlaprobe.probes.ties import ranges
from vlaprobe.reports.sections import Section

TITLE = "What the hidden states add beyond task and time"
BASELINE_NAMES = {"task": "task", "task_time": "task × time"}


def _num(v: Json, sign: bool = False) -> str:
    if not isinstance(v, (int, float)):
        return "–"
    return f"{v:+.3f}" if sign else f"{v:.3f}"


def _largest(values: list[Json]) -> int | None:
    """Position of the largest defined value, or None."""
    defined = [(v, i) for i, v in enumerate(values) if isinstance(v, (int, float))]
    return max(defined)[1] if defined else None


def conditional_headline(head: str, h: HeadResult, layers: list[int]) -> str | None:
    """One sentence: does any layer add information beyond the task x time baseline beyond its interval?
    None when the run has no conditional probing over it."""
    p = h.conditional_task_time
    if p is None:
        return None
    base = f"{_num(p.features.value[0])} [{_num(p.features.low[0])}, {_num(p.features.high[0])}]"
    text = f"{head}: a probe on the task × time cells alone scores {base} {p.metric.replace('_', ' ')}"
    beyond = adds_beyond(p)
    i = _largest([p.gain.value[j] for j in beyond] if beyond else p.gain.value)
    if i is None:
        return text + "; the gains of the hidden states are undefined."
    at = beyond[i] if beyond else i
    gain = f"{_num(p.gain.value[at], True)} [{_num(p.gain.low[at], True)}, {_num(p.gain.high[at], True)}]"
    if beyond:
        which = ranges([layers[j] for j in beyond])
        return text + (
            f"; the hidden states add information beyond it at layers {which} (the gain's interval above 0; "
            f"largest gain {gain} at layer {layers[at]})."
        )
    return text + (
        f"; no layer adds information beyond it (every gain's interval reaches 0; largest gain {gain} at layer "
        f"{layers[at]})."
    )


def _rows(h: HeadResult, layers: list[int]) -> list[JsonObject]:
    """Per layer: each baseline's combined probe and gain with its interval, and whether it lies above 0."""
    parts = h.conditional()
    rows = []
    for i, layer in enumerate(layers):
        row: JsonObject = {"layer": layer}
        for name, p in parts.items():
            row[f"{name}.combined"] = p.combined.value[i]
            row[f"{name}.combined.ci"] = [p.combined.low[i], p.combined.high[i]]
            row[f"{name}.gain"] = p.gain.value[i]
            row[f"{name}.gain.ci"] = [p.gain.low[i], p.gain.high[i]]
            row[f"{name}.beyond"] = i in adds_beyond(p)
        rows.append(row)
    return rows


def _features(p: ConditionalProbe) -> JsonObject:
    return {
        "name": BASELINE_NAMES.get(p.baseline, p.baseline),
        "key": p.baseline,
        "value": p.features.value[0],
        "ci": [p.features.low[0], p.features.high[0]],
    }


def conditional_tables(evaluation: Evaluation) -> JsonObject:
    """Per head with conditional probing: headline, the features-only probes, and the per-layer rows."""
    layers = list(evaluation.layers)
    out: JsonObject = {}
    for head, h in evaluation.heads.items():
        parts = h.conditional()
        if not parts:
            continue
        out[head] = {
            "headline": conditional_headline(head, h, layers),
            "metric": next(iter(parts.values())).metric,
            "baselines": [_features(p) for p in parts.values()],
            "rows": _rows(h, layers),
        }
    return out


def conditional_section(evaluation: Evaluation) -> Section | None:
    """The section, when the run has conditional probing."""
    tables = conditional_tables(evaluation)
    if not tables:
        return None
    return Section(
        id="conditional",
        title=TITLE,
        template="conditional.html",
        data={"heads": tables, "resamples": evaluation.bootstrap.resamples},
    )
