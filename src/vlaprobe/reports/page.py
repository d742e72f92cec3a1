"""The report's HTML page, rendered from the Jinja2 templates in ``templates/`` into one self-contained file."""

from __future__ import annotations

import base64
import json
from collections.abc import Sequence
from dataclasses import dataclass

import jinja2

from vlaprobe.files import Json, JsonObject
from vlaprobe.probes.results import Evaluation
from vlaprobe.reports.figures import metric_label
from vlaprobe.reports.sections import Section

BEST_COLUMNS = (
    ("probe.accuracy", "accuracy"),
    ("baseline.accuracy", "majority baseline"),
    ("control.accuracy", "shuffled control"),
    ("selectivity.accuracy", "selectivity"),
    ("probe.balanced_accuracy", "balanced accuracy"),
    ("baseline.balanced_accuracy", "majority baseline (bal.)"),
    ("time_baseline.balanced_accuracy", "time baseline (bal.)"),
    ("selectivity_time.balanced_accuracy", "selectivity over the time baseline"),
    ("task_baseline.balanced_accuracy", "task baseline (bal.)"),
    ("task_time_baseline.balanced_accuracy", "task × time baseline (bal.)"),
    ("selectivity_task_time.balanced_accuracy", "selectivity over the task × time baseline"),
    ("probe.f1", "F1"),
    ("probe.auprc", "AUPRC"),
    ("baseline.auprc", "AUPRC baseline"),
    ("observer.accuracy", "observer accuracy"),
)
"""Columns of the best-layer tables: (key in ``tables.json`` rows, heading); absent parts are left out."""


@dataclass
class Figure:
    """One figure of the page: its files' stem, caption and PNG bytes (embedded)."""

    stem: str
    caption: str
    png: bytes

    @property
    def base64(self) -> str:
        return base64.b64encode(self.png).decode()


def _fmt(value: Json, ci: Json = None, sd: Json = None) -> str:
    """A figure with its interval and spread, as HTML-safe text ("–" when undefined)."""
    if value is None:
        return "–"
    text = f"{value:.3f}" if isinstance(value, float) else str(value)
    if sd is not None:
        text += f" ± {sd:.3f}"
    if ci and ci[0] is not None and ci[1] is not None:
        text += f" [{ci[0]:.3f}, {ci[1]:.3f}]"
    return text


def _environment(packages: Sequence[str] = ()) -> jinja2.Environment:
    """The page's templates, then those of the packages whose sections are on the page."""
    names = dict.fromkeys(["vlaprobe.reports", *packages])
    env = jinja2.Environment(
        loader=jinja2.ChoiceLoader([jinja2.PackageLoader(name, "templates") for name in names]),
        autoescape=True,
        undefined=jinja2.StrictUndefined,
        trim_blocks=True,
        lstrip_blocks=True,
    )
    env.filters["fmt"] = _fmt
    env.filters["metric_label"] = metric_label
    env.filters["tojson_pretty"] = lambda v: json.dumps(v, indent=1)
    return env


def render_page(
    title: str,
    evaluation: Evaluation,
    tables: JsonObject,
    figures: Sequence[Figure],
    sections: Sequence[Section] = (),
) -> str:
    """The whole page: ``page.html`` with the evaluation, the best-layer tables, figures and sections."""
    columns = {
        head: [c for c in BEST_COLUMNS if any(c[0] in r for r in t["best_layer"]["rows"])]
        for head, t in tables.items()
    }
    return (
        _environment([s.package for s in sections])
        .get_template("page.html")
        .render(
            title=title,
            ev=evaluation,
            tables=tables,
            columns=columns,
            figures=figures,
            sections=sections,
        )
    )
