"""`vlaprobe failures` for people: the table it prints and the report's section (the figures' table, SAFE's ROC
curves and score-vs-time bands, what drove the cognition's alarms), rendered by
``templates/failures_section.html`` of this package."""

from __future__ import annotations

import base64
from collections import Counter
from collections.abc import Sequence
from dataclasses import asdict
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from vlaprobe.cognition.failures import FAILURES_FILE, AlarmCause, FailuresResult, read_failures
from vlaprobe.probes.bootstrap import Estimate

if TYPE_CHECKING:
    from vlaprobe.reports.figures import Rendered
    from vlaprobe.reports.sections import Section


def table(result: FailuresResult) -> str:
    """The figures as lines for people."""

    def f(x: Estimate) -> str:
        if x.value is None:
            return "n/a"
        return f"{x.value:.3g} [{'n/a' if x.low is None else f'{x.low:.3g}'}, {'n/a' if x.high is None else f'{x.high:.3g}'}]"

    lines = [
        f"{result.episodes} episodes, {result.failed} failed ({result.known_failure_steps} with a known failure step);"
        f" cognition on {result.atoms}, probe layer {result.layer}, alpha {result.alpha}, {result.folds} folds"
        f" (at least {result.calibration_episodes} calibration successes each)",
    ]
    for p in result.predictors:
        aucs = "  ".join(f"AUC@{t} {f(v)}" for t, v in p.auc.items())
        aucs += "  " + "  ".join(f"AUC@step{t} {f(v)}" for t, v in p.auc_at_step.items())
        lines.append(f"{p.name:14s} {aucs}")
        lines.append(
            f"{'':14s} detected {f(p.detection_rate)}  lead to end {f(p.lead_to_end)}  lead to failure step "
            f"{f(p.lead_to_failure_step)}  false-alarm rate {f(p.false_alarm_rate)}  per 100 steps "
            f"{f(p.false_alarms_per_100_steps)}"
        )
        if p.alarm_drivers:
            lines.append(f"{'':14s} alarm drivers {p.alarm_drivers}")
        if p.alarms:
            lines.append(f"{'':14s} alarm atoms {alarm_atoms(p.alarms)}")
    lines.append(f"token uncertainty: {result.token_uncertainty}")
    if result.token_match is not None:
        lines.append(
            f"recomputed greedy tokens equal the stored ones at {result.token_match:.1%} of the steps"
        )
    return "\n".join(lines)


def report_section(probes: Path) -> Section | None:
    """The report's failure-prediction section when ``failures.json`` is in the probe folder (``vlaprobe
    failures --out`` that folder), else None; it renders ``templates/failures_section.html`` of this package."""
    if not (Path(probes) / FAILURES_FILE).is_file():
        return None
    from vlaprobe.reports.sections import Section

    result = read_failures(probes)
    data = {
        "result": asdict(result),
        "figures": [figure_data(*f) for f in figures(result)],
        "alarm_atoms": {p.name: alarm_atoms(p.alarms) for p in result.predictors},
    }
    return Section(
        id="failures",
        title="Failure prediction",
        template="failures_section.html",
        data=data,
        package="vlaprobe.cognition",
    )


def alarm_atoms(causes: Sequence[AlarmCause], top: int = 8) -> dict[str, int]:
    """The beliefs most often involved in the first alarms (violated rules' atoms and the pending subgoal)."""
    return dict(Counter(a for c in causes for a in c.atoms).most_common(top))


def figure_data(caption: str, rendered: Rendered) -> dict[str, str]:
    """A figure as the section's template embeds it."""
    return {"caption": caption, "base64": base64.b64encode(rendered.png).decode()}


def figures(result: FailuresResult, dpi: int = 110) -> list[tuple[str, Rendered]]:
    """SAFE's two figures, one panel per predictor: the ROC curves of the running score at each normalised time,
    and the running score's median and interquartile band over normalised time, successes against failures
    (none for a file without them, version 1)."""
    from vlaprobe.reports.figures import Series, curves

    with_roc = [p for p in result.predictors if p.roc]
    with_bands = [p for p in result.predictors if p.bands is not None and p.bands.times]
    out = []
    if with_roc:
        diagonal = Series("chance", np.array([0.0, 1.0]), style=":", x=np.array([0.0, 1.0]))
        panels = {
            p.name: [
                *(Series(f"τ = {t}", np.array(r.tpr), x=np.array(r.fpr)) for t, r in p.roc.items() if r.fpr),
                diagonal,
            ]
            for p in with_roc
        }
        caption = "ROC curves of each predictor's running score at normalised times τ (failures positive, out of fold)"
        out.append(
            (
                caption,
                curves(
                    panels, np.array([0.0, 1.0]), caption, dpi, "false-positive rate", "true-positive rate"
                ),
            )
        )
    if with_bands:
        panels = {}
        for p in with_bands:
            b = p.bands
            assert b is not None
            panels[p.name] = [
                Series(label, np.array(g.median), np.array(g.low), np.array(g.high))
                for label, g in (("successes", b.success), ("failures", b.failure))
                if g.median
            ]
        times = np.array(with_bands[0].bands.times)  # type: ignore[union-attr]
        caption = "Running score over normalised time: median and interquartile band, successes vs failures"
        out.append((caption, curves(panels, times, caption, dpi, "normalised time", "running score")))
    return out
