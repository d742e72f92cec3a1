"""The report's matched-steps section: what the probes rank right where task and time cannot help.

Reads each head's ``matched`` and ``conditional_families`` of ``evaluation.json``
(:mod:`vlaprobe.probes.matched`): at the head's best layer, the AUC within task x time cells of all its atoms
and of each atom family, against 0.5 and the observer control (the paired difference), and the conditional
gain over task x time per family, each with its 95 % interval.
"""

from __future__ import annotations

from vlaprobe.files import Json, JsonObject
from vlaprobe.probes.results import Evaluation, HeadResult, Level
from vlaprobe.reports.sections import Section

TITLE = "Matched steps: same task, same time, different state"


def _at(level: Level | None, layer: int, column: int | None = None) -> JsonObject:
    """{value, ci} of one entry of a per-layer (column None) or per-layer-and-family level."""
    if level is None:
        return {"value": None, "ci": [None, None]}

    def pick(x: list[Json]) -> Json:
        v = x[layer]
        return v[column] if isinstance(v, list) and column is not None else v

    return {"value": pick(level.value), "ci": [pick(level.low), pick(level.high)]}


def _rows(h: HeadResult, i: int) -> list[JsonObject]:
    """The head's atoms together, then each family, at layer position ``i``."""
    m = h.matched
    assert m is not None
    gain = h.conditional_families.get("task_time")
    pairs = {a: n for a, n in zip(h.atoms, m.pairs, strict=True)}
    rows: list[JsonObject] = [
        {
            "family": "all atoms",
            "atoms": len(h.atoms),
            "pairs": sum(n for n in m.pairs if isinstance(n, int)),
            "probe": _at(m.probe.layer, i),
            "observer": _at(m.observer.layer if m.observer else None, i),
            "difference": _at(m.difference.layer if m.difference else None, i),
            "gain": _at(h.conditional_task_time.gain if h.conditional_task_time else None, i),
        }
    ]
    for j, (name, atoms) in enumerate(h.families.items()):
        rows.append(
            {
                "family": name,
                "atoms": len(atoms),
                "pairs": sum(int(pairs[a] or 0) for a in atoms),
                "probe": _at(m.family, i, j),
                "observer": _at(m.observer_family, i, j),
                "difference": _at(m.difference_family, i, j),
                "gain": _at(gain, i, j),
            }
        )
    return rows


def matched_tables(evaluation: Evaluation) -> JsonObject:
    """Per head with the matched-steps control: its best layer and the rows of :func:`_rows` there."""
    out: JsonObject = {}
    for head, h in evaluation.heads.items():
        if h.matched is None:
            continue
        out[head] = {"layer": h.best.layer, "paired": h.matched.paired, "rows": _rows(h, h.best.index)}
    return out


def matched_section(evaluation: Evaluation) -> Section | None:
    """The section, when the run has the matched-steps control (evaluation.json version 5 on)."""
    tables = matched_tables(evaluation)
    if not tables:
        return None
    observer = evaluation.controls.observer
    return Section(
        id="matched",
        title=TITLE,
        template="matched.html",
        data={
            "heads": tables,
            "resamples": evaluation.bootstrap.resamples,
            "observer": observer.model_id if observer else None,
            "cells": next(h.matched.cells for h in evaluation.heads.values() if h.matched),
        },
    )
