"""Within-task versus cross-task probes, predicate by predicate (``vlaprobe compare-splits``).

Reads two probe folders trained on the same store, one with the default within-task episode split and one
with ``--split leave-one-task-out``, and lists per head and predicate the metric at each folder's best layer
of that head, with its interval, and the drop from within-task to cross-task.
"""

from __future__ import annotations

import json
from dataclasses import asdict, dataclass
from pathlib import Path

from vlaprobe.configs.hypotheses import CompareSplitsConfig
from vlaprobe.errors import VlaprobeError
from vlaprobe.probes.results import HeadResult, read_evaluation


@dataclass(frozen=True)
class PredicateRow:
    """One predicate under both splits (None: not probed under that split)."""

    head: str
    predicate: str
    within: float | None
    within_interval: tuple[float | None, float | None]
    across: float | None
    across_interval: tuple[float | None, float | None]

    @property
    def drop(self) -> float | None:
        return None if self.within is None or self.across is None else self.within - self.across


def _at_best(head: HeadResult, metric: str) -> dict[str, tuple[float | None, float | None, float | None]]:
    """predicate -> (value, low, high) at the head's best layer."""
    i = head.best.index
    level = head.probe[metric].predicate
    return {p: (level.value[i][k], level.low[i][k], level.high[i][k]) for k, p in enumerate(head.predicates)}


def split_comparison(within: Path, across: Path, metric: str = "balanced_accuracy") -> list[PredicateRow]:
    """Rows for every (head, predicate) probed under either split, heads and predicates in figure order."""
    a, b = read_evaluation(Path(within)), read_evaluation(Path(across))
    rows = []
    for head in a.heads:
        ha, hb = a.heads.get(head), b.heads.get(head)
        if ha is None or hb is None:
            continue
        if metric not in ha.probe or metric not in hb.probe:
            raise VlaprobeError(f"no {metric} in both evaluations; use one of {sorted(ha.probe)}")
        va, vb = _at_best(ha, metric), _at_best(hb, metric)
        for p in [*ha.predicates, *[q for q in hb.predicates if q not in va]]:
            x, y = va.get(p, (None, None, None)), vb.get(p, (None, None, None))
            rows.append(PredicateRow(head, p, x[0], (x[1], x[2]), y[0], (y[1], y[2])))
    return rows


def main(cfg: CompareSplitsConfig) -> int:
    rows = split_comparison(cfg.within, cfg.across, cfg.metric)
    if cfg.json:
        print(json.dumps([{**asdict(r), "drop": r.drop} for r in rows]))
        return 0

    def fmt(v: float | None) -> str:
        return "   –  " if v is None else f"{v:6.3f}"

    print(
        f"{'head':<7}{'predicate':<22}{'within':>8}{'across':>8}{'drop':>8}   ({cfg.metric} at each best layer)"
    )
    for r in rows:
        print(f"{r.head:<7}{r.predicate:<22}{fmt(r.within):>8}{fmt(r.across):>8}{fmt(r.drop):>8}")
    return 0
