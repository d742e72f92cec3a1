"""Observers side by side (issue 38, item 2): per probe folder and head, the best layer with its tied set, the
shuffled-label control at that layer and the probe's gain over it, the task and task x time baselines, the
conditional gain over task x time, the matched-steps AUC per family against
the observer control, and the validation figure (the C search's cross-validated balanced accuracy on the
training episodes), as one Markdown table per head; then per atom family the conditional gain over task x time.

    python scripts/observer_table.py tiny-libero=runs/must-look/varied/probes-tiny-libero \
        tiny-libero-diverse=runs/must-look/varied/probes-diverse

Every figure is read from the folders' ``evaluation.json``; nothing is recomputed. Intervals are the 95 %
bootstrap intervals over test episodes that ``vlaprobe train`` wrote.
"""

from __future__ import annotations

import argparse
import sys

import numpy as np

from vlaprobe.errors import VlaprobeError
from vlaprobe.probes.results import HeadResult, Level, arr, read_evaluation

METRIC = "balanced_accuracy"


def _at(level: Level, index: int | None = None) -> str:
    """'value [low, high]' of a per-layer (index given) or a one-row level."""
    pick = (lambda a: a[index]) if index is not None else (lambda a: a.reshape(-1)[0])
    v, lo, hi = (float(pick(arr(x))) for x in (level.value, level.low, level.high))
    if np.isnan(v):
        return "–"
    return f"{v:.3f} [{lo:.3f}, {hi:.3f}]" if not (np.isnan(lo) or np.isnan(hi)) else f"{v:.3f}"


def _validation(h: HeadResult, layers: list[int]) -> str:
    """The best cross-validated score over layers at each layer's chosen C (training episodes only)."""
    if h.fit is None or h.fit.cv_score is None:
        return "–"
    score = arr(h.fit.cv_score)
    grid = np.log(np.asarray(h.fit.c_grid, dtype=float))
    chosen = [
        int(np.argmin(abs(grid - np.log(float(c))))) if isinstance(c, (int, float)) else -1 for c in h.fit.c
    ]
    per_layer = np.array([score[i, j] if j >= 0 else np.nan for i, j in enumerate(chosen)])
    if np.all(np.isnan(per_layer)):
        return "–"
    best = int(np.nanargmax(per_layer))
    return f"{per_layer[best]:.3f} (layer {layers[best]})"


def _conditional(h: HeadResult, layers: list[int]) -> str:
    c = h.conditional_task_time
    if c is None:
        return "–"
    gain = arr(c.gain.value)
    best = int(np.nanargmax(gain))
    return f"{_at(c.gain, best)} at layer {layers[best]}"


def _matched(h: HeadResult, family: str) -> str:
    m = h.matched
    if m is None or family not in h.families:
        return "–"
    f = list(h.families).index(family)
    i = h.best.index
    probe = float(arr(m.family.value)[i, f])
    observer = float(arr(m.observer_family.value)[i, f]) if m.observer_family is not None else float("nan")
    diff = m.difference_family
    d = ""
    if diff is not None:
        lo, hi = float(arr(diff.low)[i, f]), float(arr(diff.high)[i, f])
        d = f", difference [{lo:+.3f}, {hi:+.3f}]"
    return f"{probe:.3f} vs {observer:.3f}{d}"


def rows(name: str, h: HeadResult, layers: list[int]) -> list[str]:
    b = h.best
    tied = ",".join(str(t) for t in b.tied) or str(b.layer)
    parts = [
        name,
        f"{b.layer} {{{tied}}}",
        f"{b.value:.3f} [{b.low:.3f}, {b.high:.3f}]"
        if b.value is not None and b.low is not None and b.high is not None
        else "–",
        _at(h.control[METRIC].layer, b.index) if h.control else "–",
        _at(h.selectivity[METRIC].layer, b.index) if h.selectivity else "–",
        _at(h.task_baseline[METRIC].layer) if h.task_baseline else "–",
        _at(h.task_time_baseline[METRIC].layer) if h.task_time_baseline else "–",
        _conditional(h, layers),
        _matched(h, "grasped"),
        _matched(h, "on(bowl, plate)"),
        _validation(h, layers),
    ]
    return ["| " + " | ".join(parts) + " |"]


def family_rows(name: str, h: HeadResult, layers: list[int]) -> list[str]:
    """Per atom family, the conditional gain over task x time at the head's best layer and the largest over the
    layers, and how many layers' gains lie above 0 beyond their interval (item 4 of issue 38)."""
    level = h.conditional_families.get("task_time")
    if level is None:
        return []
    v, lo, hi = (arr(x) for x in (level.value, level.low, level.high))
    out, b = [], h.best.index
    for j, family in enumerate(h.families):
        if np.all(np.isnan(v[:, j])):
            continue
        top = int(np.nanargmax(v[:, j]))
        above = int(np.sum(lo[:, j] > 0))
        cells = [name, family, f"{v[b, j]:+.3f} [{lo[b, j]:+.3f}, {hi[b, j]:+.3f}]",
                 f"{v[top, j]:+.3f} [{lo[top, j]:+.3f}, {hi[top, j]:+.3f}] at layer {layers[top]}",
                 f"{above} of {len(layers)}"]  # fmt: skip
        out.append("| " + " | ".join(cells) + " |")
    return out


FAMILY_HEADER = (
    "| observer | family | conditional gain over task x time, best layer | largest | layers above 0 |\n"
    "| --- | --- | --- | --- | --- |"
)

HEADER = (
    "| observer | best layer {tied} | balanced accuracy | shuffled labels | probe - shuffled | task baseline | task x time baseline | conditional gain over "
    "task x time (best) | matched AUC grasped, probe vs control | matched AUC on(bowl, plate) | validation (CV) |\n"
    "| --- | --- | --- | --- | --- | --- | --- | --- | --- | --- | --- |"
)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("folders", nargs="+", help="NAME=PROBE_FOLDER, one per observer")
    args = parser.parse_args(argv)
    try:
        pairs = [tuple(x.split("=", 1)) for x in args.folders]
        if any(len(p) != 2 for p in pairs):
            raise VlaprobeError("give each probe folder as NAME=FOLDER, e.g. tiny-libero=runs/x/probes")
        evals = [(n, read_evaluation(f)) for n, f in pairs]
    except VlaprobeError as e:
        print(f"observer_table: {e}", file=sys.stderr)
        return 2
    heads = sorted({h for _, ev in evals for h in ev.heads})
    for head in heads:
        print(f"\n{head} head\n\n{HEADER}")
        for name, ev in evals:
            if head in ev.heads:
                print("\n".join(rows(name, ev.heads[head], ev.layers)))
        print(f"\n{head} head, per atom family\n\n{FAMILY_HEADER}")
        for name, ev in evals:
            if head in ev.heads:
                print("\n".join(family_rows(name, ev.heads[head], ev.layers)))
    return 0


if __name__ == "__main__":
    sys.exit(main())
