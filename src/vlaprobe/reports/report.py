"""``vlaprobe report``: heatmaps, metric-versus-layer curves, their data as CSV/JSON, one HTML page.

Everything comes from the probe folder's ``evaluation.json`` (no recomputation). Files written:

- ``heatmap_<metric>.{png,svg,csv,json}``: layers x predicates (object then action predicates, the paper's
  order) of the probes' per-predicate mean; ``heatmap_selectivity`` (probe minus shuffled-label control)
  and ``heatmap_observer_<metric>`` when those controls exist;
- ``curves_<head>.{png,svg,csv,json}``: every metric's mean over the head's atoms versus layer, with 95%
  bootstrap bands, next to the majority baseline, the shuffled-label control and the observer control;
- ``tables.json``: the tables of the page (per-predicate figures at the best layer and the layers tied with it,
  dropped atoms); ``conditional.json``: the conditional-probing section's per-layer gains, when computed;
  ``matched.json``: the matched-steps section's figures per atom family, when computed;
- ``index.html``: a self-contained page (figures embedded as base64 PNG) with the split, dataset size,
  dropped atoms, baselines and every plot, rendered from the Jinja2 templates in ``templates/``. Written last.

More sections plug in as a :class:`~vlaprobe.reports.sections.Section` (a template and its data), passed to
:func:`write_report` or found by a provider listed in :data:`~vlaprobe.reports.sections.SECTION_PROVIDERS`.
"""

from __future__ import annotations

import csv
import io
import json
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from vlaprobe.configs.checks import REPORT_FOLDER, check_report
from vlaprobe.configs.report import ReportConfig
from vlaprobe.files import Json, JsonObject, check_owned_folder, mark_folder, write_atomic
from vlaprobe.probes.results import PARTS, Evaluation, HeadResult, arr, read_evaluation
from vlaprobe.probes.ties import describe
from vlaprobe.reports.conditional import conditional_headline, conditional_section
from vlaprobe.reports.figures import Rendered, Series, TieMarks, curves, heatmap, metric_label
from vlaprobe.reports.matched import matched_section
from vlaprobe.reports.page import Figure, render_page
from vlaprobe.reports.sections import Section, find_sections
from vlaprobe.symbols.vocabulary import ACTION_PREDICATES

REPORT_FILE = "index.html"


def write_report(cfg: ReportConfig, sections: Sequence[Section] = ()) -> Path:
    """Write every figure, its data and the HTML page; return the page's path.

    ``sections`` are added to the page after the figures, followed by those the registered providers find
    for this probe folder (the diversity of its store, H1/H2 when computed). ``vlaprobe.pipeline.report`` adds
    the cognition monitor's section."""
    check_report(cfg)
    out = Path(cfg.out) if cfg.out is not None else Path(cfg.probes).parent / "report"
    check_owned_folder(out, REPORT_FOLDER)  # a folder of someone else's files is never written into
    evaluation = read_evaluation(cfg.probes)
    out.mkdir(parents=True, exist_ok=True)
    mark_folder(out, REPORT_FOLDER.owner)
    title = cfg.title or f"Probing {evaluation.model_id} on {evaluation.suite} ({evaluation.pooling} pooling)"
    figures = _heatmaps(out, evaluation, cfg) + _curve_figures(out, evaluation, cfg)
    tables = _tables(evaluation)
    write_atomic(out / "tables.json", json.dumps(tables, indent=1) + "\n")
    conditional = conditional_section(evaluation)
    if conditional is not None:
        write_atomic(out / "conditional.json", json.dumps(conditional.data, indent=1) + "\n")
    matched = matched_section(evaluation)
    if matched is not None:
        write_atomic(out / "matched.json", json.dumps(matched.data, indent=1) + "\n")
    extra = [*(s for s in (conditional, matched) if s), *sections, *find_sections(Path(cfg.probes))]
    page = out / REPORT_FILE
    write_atomic(page, render_page(title, evaluation, tables, figures, extra))
    return page


def _heatmap_blocks(evaluation: Evaluation, metric: str) -> list[tuple[str, str, str, str]]:
    """(part, metric, file stem, caption) of each heatmap: the probes, then the controls this run has."""
    label = metric_label(metric)
    caption = f"Per-predicate {label} of the probes (▸ in a head's first column: the layers tied with its best layer, ★ the best)"
    blocks = [("probe", metric, f"heatmap_{metric}", caption)]
    if any(h.selectivity is not None for h in evaluation.heads.values()):
        caption = "Selectivity: probe accuracy minus shuffled-label control accuracy"
        blocks.append(("selectivity", "accuracy", "heatmap_selectivity", caption))
    if evaluation.controls.observer is not None:
        observer = evaluation.controls.observer.model_id
        caption = f"Per-predicate {label} of probes on the observer control ({observer}; ▸ ★ its own tie set)"
        blocks.append(("observer", metric, f"heatmap_observer_{metric}", caption))
    return blocks


def _heatmaps(out: Path, evaluation: Evaluation, cfg: ReportConfig) -> list[Figure]:
    """Write the heatmaps (layers x predicates) with their data; return them as page figures."""
    layers = list(evaluation.layers)
    figures = []
    for part, metric, stem, caption in _heatmap_blocks(evaluation, cfg.metric):
        columns, values, rows = _heatmap_data(evaluation, part, metric)
        tied = _tied_marks(evaluation, part, columns)
        split_after = sum(1 for c in columns if c.split(": ", 1)[0] != "action")
        diverging = part == "selectivity"
        bound = float(np.nanmax(np.abs(values))) if diverging and np.isfinite(values).any() else None
        rendered = heatmap(
            values,
            layers,
            columns,
            caption,
            metric_label(metric) if not diverging else "selectivity",
            cfg.dpi,
            split_after=split_after,
            vmin=-bound if bound else None,
            vmax=bound,
            cmap="RdBu_r" if diverging else "viridis",
            marks=tied,
        )
        data = {"layers": layers, "columns": columns, "part": part, "metric": metric, "values": _list(values)}
        if tied:
            data["tied"] = {head: m.tied_layers for head, m in tied.items()}
            data["best"] = {head: m.best_layer for head, m in tied.items()}
        _write_figure(out, stem, rendered, rows, data)
        figures.append(Figure(stem, caption, rendered.png))
    return figures


def _tied_marks(evaluation: Evaluation, part: str, columns: list[str]) -> dict[str, TieMarks]:
    """Per head: its columns of the heatmap and the rows of its best layer and the layers tied with it (the
    probes' heatmap and the observer's, each with its own best layer)."""
    if part not in ("probe", "observer"):
        return {}
    layers = list(evaluation.layers)
    marks = {}
    for head, h in evaluation.heads.items():
        best = h.best if part == "probe" else h.observer_best
        cols = [j for j, c in enumerate(columns) if c.split(": ", 1)[0] == head]
        if best is None or not cols:
            continue
        tied = [t for t in best.tied if t in layers] or [best.layer]
        marks[head] = TieMarks(
            cols[0], [layers.index(t) for t in tied], layers.index(best.layer), tied, best.layer
        )
    return marks


def _curve_figures(out: Path, evaluation: Evaluation, cfg: ReportConfig) -> list[Figure]:
    """Write each head's metric-versus-layer curves with their data; return them as page figures."""
    layers = list(evaluation.layers)
    figures = []
    for head, h in evaluation.heads.items():
        panels, rows = _curve_data(h, layers, evaluation.metrics)
        caption = f"{head} atoms: mean over {len(h.atoms)} probed atoms per layer, 95% bootstrap bands"
        rendered = curves(panels, layers, caption, cfg.dpi)
        series = {
            m: {s.label: {"value": _list(s.value), "low": _list(s.low), "high": _list(s.high)} for s in ss}
            for m, ss in panels.items()
        }
        _write_figure(
            out, f"curves_{head}", rendered, rows, {"layers": layers, "head": head, "series": series}
        )
        figures.append(Figure(f"curves_{head}", caption, rendered.png))
    return figures


def _tables(evaluation: Evaluation) -> JsonObject:
    """The page's tables per head: headline, best layer per predicate, dropped atoms, skipped predicates."""
    return {
        head: {
            "headline": headline(head, h),
            "conditional_headline": conditional_headline(head, h, list(evaluation.layers)),
            "best_layer": _best_table(h, evaluation.metrics),
            "dropped": [d.__dict__ for d in h.dropped],
            "skipped_predicates": h.skipped_predicates,
            "c_warning": None if h.fit is None else h.fit.edge_warning(head),
        }
        for head, h in evaluation.heads.items()
    }


def headline(head: str, h: HeadResult) -> str:
    """One sentence: the best layer, its figure with interval, and whether it beats the task x time baseline
    beyond its interval (the paired bootstrap interval of probe minus baseline lies above 0)."""
    best, metric = h.best, h.best.metric
    value = f"{metric_label(metric)} {_num(best.value)} [{_num(best.low)}, {_num(best.high)}]"
    text = f"{head}: {describe(best.layer, best.tied or [best.layer])}; {value}"
    tt, sel = h.part("task_time_baseline"), h.part("selectivity_task_time")
    if tt is None or metric not in tt:
        return text + "."
    level = tt[metric].layer
    text += f"; task × time baseline {_num(level.value[0])} [{_num(level.low[0])}, {_num(level.high[0])}]"
    if sel is None or metric not in sel:
        return text + "."
    diff = sel[metric].layer
    low, high, value = diff.low[best.index], diff.high[best.index], diff.value[best.index]
    if low is not None and low > 0:
        verdict = "beats it beyond its interval"
    elif high is not None and high < 0:
        verdict = "is below it beyond its interval"
    else:
        verdict = "does not beat it beyond its interval"
    return text + f": the best layer {verdict} (difference {_num(value)} [{_num(low)}, {_num(high)}])."


def _num(v: float | None) -> str:
    return "–" if v is None else f"{v:.3f}"


# -- data of the figures -------------------------------------------------------------------------------


def _list(x: np.ndarray | None) -> Json:
    if x is None:
        return None
    a = np.round(np.asarray(x, float), 5)
    return np.where(np.isfinite(a), a, np.array(None)).tolist()  # NaN -> null, any shape


def _heatmap_data(evaluation: Evaluation, part: str, metric: str) -> tuple[list[str], np.ndarray, list[dict]]:
    """Columns "head: predicate" in figure order, values (layers, columns), and the long-format CSV rows."""
    layers = evaluation.layers
    columns, blocks, rows = [], [], []
    for head, h in evaluation.heads.items():
        summaries = h.part(part)
        if summaries is None or metric not in summaries:
            continue
        s = summaries[metric].predicate
        value, low, high, count = arr(s.value), arr(s.low), arr(s.high), s.count
        base = arr(h.baseline[metric].predicate.value)[0]
        for j, p in enumerate(h.predicates):
            columns.append(f"{head}: {p}")
            for i, layer in enumerate(layers):
                rows.append(
                    {
                        "head": head,
                        "predicate": p,
                        "layer": layer,
                        "metric": metric,
                        "part": part,
                        "value": _cell(value[i, j]),
                        "ci_low": _cell(low[i, j]),
                        "ci_high": _cell(high[i, j]),
                        "atoms": None if count is None else count[i][j],
                        "majority_baseline": _cell(base[j]),
                    }
                )
        blocks.append(value)
    if not blocks:
        return [], np.zeros((len(layers), 0)), []
    order = _figure_order(columns)
    values = np.concatenate(blocks, axis=1)[:, order]
    return [columns[i] for i in order], values, rows


def _figure_order(columns: list[str]) -> list[int]:
    """Object-head columns first, then action predicates (each head already in the paper's order)."""

    def key(i: int) -> tuple[int, int]:
        head, pred = columns[i].split(": ", 1)
        return (1 if head == "action" or pred in ACTION_PREDICATES else 0, i)

    return sorted(range(len(columns)), key=key)


def _cell(v: float) -> float | None:
    return None if not np.isfinite(v) else round(float(v), 5)


CURVE_SERIES = (
    ("probe", "probe", "-"),
    ("observer", "observer control", "-."),
    ("control", "shuffled-label control", "--"),
    ("task_time_baseline", "task × time baseline", "s:"),
    ("task_baseline", "task baseline", "v:"),
    ("time_baseline", "time baseline", "^:"),
    ("baseline", "majority baseline", ":"),
)
"""(part, legend label, line style) of the curves, drawn in this order."""


def _curve_data(
    h: HeadResult, layers: list[int], metrics: list[str]
) -> tuple[dict[str, list[Series]], list[dict]]:
    """Per metric: the probes, baseline, shuffled control and observer as mean-over-atoms series."""
    panels: dict[str, list[Series]] = {}
    rows: list[dict] = []
    n = len(layers)
    for m in metrics:
        series = []
        for part, label, style in CURVE_SERIES:
            summaries = h.part(part)
            if summaries is None or m not in summaries:
                continue
            s = summaries[m].layer
            low: np.ndarray | None
            high: np.ndarray | None
            value, low, high = arr(s.value), arr(s.low), arr(s.high)
            if len(value) == 1:  # the baseline does not depend on the layer
                value, low, high = (np.repeat(a, n) for a in (value, low, high))
            if not np.isfinite(low).any():
                low = high = None
            series.append(Series(label, value, low, high, style))
            for i, layer in enumerate(layers):
                rows.append(
                    {
                        "metric": m,
                        "series": label,
                        "layer": layer,
                        "value": _cell(value[i]),
                        "ci_low": None if low is None else _cell(low[i]),
                        "ci_high": None if high is None else _cell(high[i]),
                    }
                )
        panels[m] = series
    return panels, rows


def _at(values: list[Json], index: tuple[int, ...]) -> Json:
    for k in index:
        values = values[k]
    return values


def _best_table(h: HeadResult, metrics: list[str]) -> JsonObject:
    """Per predicate at the head's best layer: every metric with CI, baseline, control and selectivity.

    ``<part>.<metric>.defined`` is the number of bootstrap resamples in which the figure was defined over all
    of its atoms; ``control.<metric>.sd`` the shuffled control's spread over its label permutations."""
    best = h.best
    i = best.index  # position of the best layer in the per-layer arrays
    rows = []
    for j, p in enumerate([*h.predicates, "(all atoms)"]):
        row: JsonObject = {"predicate": p}
        for m in metrics:
            by_predicate = j < len(h.predicates)
            for part in PARTS:
                summaries = h.part(part)
                if summaries is None or m not in summaries:
                    continue
                s = summaries[m].predicate if by_predicate else summaries[m].layer
                k = 0 if part.endswith("baseline") else i  # a baseline has one row for all layers
                at = (k, j) if by_predicate else (k,)
                row[f"{part}.{m}"] = _at(s.value, at)
                if part in ("probe", "selectivity", "selectivity_task_time", "observer") or part.endswith(
                    "baseline"
                ):
                    row[f"{part}.{m}.ci"] = [_at(s.low, at), _at(s.high, at)]
                    row[f"{part}.{m}.defined"] = _at(s.defined, at)
            if h.control_spread is not None and m in h.control_spread:
                spread = h.control_spread[m]
                row[f"control.{m}.sd"] = spread.predicate[i][j] if by_predicate else spread.layer[i]
        rows.append(row)
    return {
        "layer": best.layer,
        "metric": best.metric,
        "value": best.value,
        "rule": best.rule,
        "tied": best.tied,
        "tied_text": describe(best.layer, best.tied or [best.layer]),
        "tie_rule": best.tie_rule,
        "rows": rows,
    }


# -- files --------------------------------------------------------------------------------------------


def _write_figure(out: Path, stem: str, rendered: Rendered, rows: list[dict], data: JsonObject) -> None:
    write_atomic(out / f"{stem}.png", rendered.png)
    write_atomic(out / f"{stem}.svg", rendered.svg)
    write_atomic(out / f"{stem}.json", json.dumps(data) + "\n")
    buf = io.StringIO()
    if rows:
        writer = csv.DictWriter(buf, fieldnames=list(rows[0]), lineterminator="\n")
        writer.writeheader()
        writer.writerows({k: "" if v is None else v for k, v in r.items()} for r in rows)
    write_atomic(out / f"{stem}.csv", buf.getvalue())
