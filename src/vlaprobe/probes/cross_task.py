"""Within-task versus cross-task probes, predicate by predicate (``vlaprobe compare-splits``).

Reads two probe folders trained on the same store, one with the default within-task episode split and one
with ``--split leave-one-task-out``, and lists per head and predicate the metric at each folder's best layer
of that head, with its interval, and the drop from within-task to cross-task.
"""

from __future__ import annotations

import json
from dataclasses import asdict, dataclass
from pathlib import Path

from vlaprobe.configs.env import same_suite
from vlaprobe.configs.hypotheses import CompareSplitsConfig
from vlaprobe.errors import VlaprobeError
from vlaprobe.probes.results import Evaluation, HeadResult, read_evaluation


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


LOTO = "leave-one-task-out"


def _split_of(ev: Evaluation) -> str | None:
    """The ``--split.by`` the evaluation's run was trained with (None: not recorded)."""
    split = ev.config.get("split")
    by = split.get("by") if isinstance(split, dict) else None
    return by if isinstance(by, str) else None


def check_pair(within: Path, across: Path, a: Evaluation, b: Evaluation) -> None:
    """Refuse two evaluations that do not make a within-task / cross-task pair of one store: the same folder
    twice, two suites, the two folders swapped or of one split, another model or other data."""
    if within.resolve() == across.resolve():
        raise VlaprobeError(
            f"--within and --across are the same folder ({within}); pass the within-task probes and the "
            f"probes trained with --split.by {LOTO} on the same store"
        )
    same_suite(f"--within {within}", a.suite, f"--across {across}", b.suite)
    kinds = _split_of(a), _split_of(b)
    if None not in kinds and not (kinds[0] != LOTO and kinds[1] == LOTO):
        if kinds[0] == LOTO and kinds[1] != LOTO:
            raise VlaprobeError(
                f"--within {within} was trained with --split.by {LOTO} and --across {across} within tasks: "
                "the folders are swapped; pass them the other way round"
            )
        raise VlaprobeError(
            f"--within {within} and --across {across} were both trained with --split.by {kinds[0]}; pass one "
            f"within-task folder and one trained with --split.by {LOTO}"
        )
    if a.model_id != b.model_id or a.pooling != b.pooling or a.dataset != b.dataset:
        raise VlaprobeError(
            f"--within {within} and --across {across} were trained on different data (model {a.model_id!r} vs "
            f"{b.model_id!r}, {a.dataset.episodes} vs {b.dataset.episodes} episodes, {a.dataset.steps} vs "
            f"{b.dataset.steps} steps); train both on the same store"
        )


def split_comparison(within: Path, across: Path, metric: str = "balanced_accuracy") -> list[PredicateRow]:
    """Rows for every (head, predicate) probed under either split, heads and predicates in figure order."""
    a, b = read_evaluation(Path(within)), read_evaluation(Path(across))
    check_pair(Path(within), Path(across), a, b)
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
