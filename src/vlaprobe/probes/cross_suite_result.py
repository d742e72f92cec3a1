"""The result of ``vlaprobe cross-suite`` (``cross_suite_<suite>.json``): dataclasses, one writer, one reader.

Format version 2: :class:`CrossSuite` with ``format`` and ``format_version``. Figures are balanced accuracies
averaged over the shared atoms defined (both classes present) on the target store's scored rows, with 95%
percentile intervals over resamples of the target store's episodes (:mod:`vlaprobe.probes.bootstrap`); None
where undefined. Version 2 adds the controls: per head the shuffled-label control (``shuffled``) and the
observer control (``observer``), and at the top how they were made (``shuffled``, ``control``). A version-1
file (without them) is read with no control.
"""

from __future__ import annotations

import json
from dataclasses import asdict, dataclass, field
from pathlib import Path

from vlaprobe.files import JsonObject, from_json, read_versioned, write_atomic
from vlaprobe.probes.bootstrap import Estimate
from vlaprobe.probes.ties import describe

FORMAT = "vlaprobe-cross-suite"
FORMAT_VERSION = 2
READS = (1, 2)
"""Format versions :func:`read_cross_suite` reads (1: without the controls)."""


@dataclass(frozen=True)
class FamilyFigure:
    """One atom family (:mod:`vlaprobe.probes.families`) at the head's best layer."""

    family: str
    atoms: int
    """Shared atoms of the family defined (both classes) on the target rows: those averaged."""
    balanced_accuracy: Estimate


@dataclass(frozen=True)
class ShuffledAt:
    """The shuffled-label control at one layer: probes fit on the source rows with permuted labels."""

    layer: int
    c: float
    """The inverse L2 strength they were fit with: the saved probes' at this layer."""
    balanced_accuracy: Estimate
    """Mean over the permutations of the balanced accuracy on the target rows (mean over the scored atoms)."""
    spread: float | None
    """Standard deviation over the permutations of that figure (None with one permutation)."""
    probe_minus_shuffled: Estimate
    """The probes minus the control at this layer, paired over the same resamples."""


@dataclass(frozen=True)
class ObserverTransfer:
    """The control observer's probes (trained on the untrained network's source store) scored on the target
    store that network observed: the same episodes, so every difference is paired over the same resamples."""

    atoms: list[str]
    """Shared atoms both probe folders probe (the figures' and the differences' atoms)."""
    scored: int
    layers: list[int]
    balanced_accuracy: list[Estimate]
    best_layer: int
    """Chosen on the target's episodes: optimistic, as the probes' own ``best_layer``."""
    tied: list[int]
    source_layer: int
    """The control probes' own best layer, chosen on the source suite."""
    at_source_layer: Estimate
    probe_minus_observer: Estimate
    """The probes at their source layer minus the control's at its source layer (both chosen without the
    target), over ``atoms``."""
    best_minus_best: Estimate
    """The probes' best layer on the target minus the control's best (both chosen on the target)."""


@dataclass(frozen=True)
class ShuffledInfo:
    """How the shuffled-label control was made."""

    permutations: int
    seed: int
    """Seed of the permutations (the probes' ``shuffle`` seed, as ``vlaprobe train`` drew them)."""
    rows: str
    """Which source rows the permuted probes were fit on."""
    c: str
    """Where their C came from."""


@dataclass(frozen=True)
class ControlInfo:
    """The observer control's inputs."""

    probes: str
    store: str
    model_id: str


@dataclass(frozen=True)
class HeadTransfer:
    """One head's probes scored on the target store over the shared atoms."""

    atoms: list[str]
    """Shared atoms: probed on the source suite and in the target store's vocabulary, in probe order."""
    scored: int
    """Shared atoms with both classes on the target's rows where they are defined (those averaged)."""
    masked_rows: int
    """(row, atom) entries left out because the row's task does not define the atom."""
    layers: list[int]
    """Hidden-state index of each entry of ``balanced_accuracy``."""
    balanced_accuracy: list[Estimate]
    """Per layer, the mean over the scored atoms."""
    best_layer: int
    """The best layer on the target's own episodes: chosen on the data it is scored on, so its figure is
    optimistic; ``at_source_layer`` is the unbiased reading."""
    tied: list[int]
    """Layers tied with the best (the best included): :data:`vlaprobe.probes.ties.TIE_RULE`."""
    source_layer: int
    """The probes' own best layer, chosen on the source suite's held-out episodes (``probes.json``)."""
    at_source_layer: Estimate
    """The balanced accuracy on the target at ``source_layer`` (a layer chosen without the target's data)."""
    majority: Estimate
    """The per-atom majority of the source store (a constant prediction: 0.5 wherever defined)."""
    time: Estimate
    """Normalised-time decile -> majority, fit on the source store's rows."""
    best_minus_time: Estimate
    """Best layer minus the time baseline, paired over the same resamples."""
    source: float | None
    """The source evaluation's balanced accuracy at the same layer over the same atoms, on its own held-out
    episodes (``evaluation.json``; None without one). A point value: the file keeps no resamples."""
    source_split: str
    """How the source evaluation held episodes out ("" without one)."""
    families: list[FamilyFigure]
    shuffled: list[ShuffledAt] = field(default_factory=list)
    """The shuffled-label control at ``source_layer`` and at ``best_layer`` (once when they are one; empty
    without the control or in a version-1 file)."""
    observer: ObserverTransfer | None = None
    """The observer control (None without ``--control-probes``)."""


@dataclass(frozen=True)
class CrossSuite:
    """Everything ``vlaprobe cross-suite`` measured."""

    probes: str
    store: str
    source_store: str
    source_suite: str
    target_suite: str
    model_id: str
    pooling: str
    episodes: int
    """Target episodes scored."""
    rows: int
    resamples: int
    seed: int
    threshold: float
    heads: dict[str, HeadTransfer]
    unshared: dict[str, list[str]]
    """Per head, the probed atoms the target vocabulary lacks (not scored)."""
    shuffled: ShuffledInfo | None = None
    control: ControlInfo | None = None


def default_path(probes: str | Path, target_suite: str) -> Path:
    """``<probes>/cross_suite_<target suite>.json``."""
    return Path(probes) / f"cross_suite_{target_suite}.json"


def write_cross_suite(path: str | Path, result: CrossSuite) -> Path:
    """Write ``result`` to ``path`` atomically; return the path."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    data: JsonObject = {"format": FORMAT, "format_version": FORMAT_VERSION, **asdict(result)}
    write_atomic(path, json.dumps(data, indent=1, allow_nan=False) + "\n")
    return path


def read_cross_suite(path: str | Path) -> CrossSuite:
    """Read a file of :func:`write_cross_suite`; a one-line error if it is missing, damaged or of another
    version."""
    path = Path(path)
    hint = "run vlaprobe cross-suite again"
    data, _ = read_versioned(path, FORMAT, "cross-suite result", READS, hint)
    data = {k: v for k, v in data.items() if k not in ("format", "format_version")}
    return from_json(CrossSuite, data, path, hint)


def _fmt(e: Estimate, sign: bool = False) -> str:
    spec = "+.3f" if sign else ".3f"
    if e.value is None:
        return "–"
    if e.low is None or e.high is None:
        return format(e.value, spec)
    return f"{format(e.value, spec)} [{format(e.low, spec)}, {format(e.high, spec)}]"


def _control_lines(r: CrossSuite, h: HeadTransfer) -> list[str]:
    """The head's controls: the shuffled-label probes per layer, the control observer's probes."""
    lines = []
    for s in h.shuffled:
        spread = (
            ""
            if s.spread is None
            else f" (sd {s.spread:.3f} over {r.shuffled.permutations if r.shuffled else '?'})"
        )
        lines.append(
            f"          shuffled labels at layer {s.layer} (C {s.c:g}): {_fmt(s.balanced_accuracy)}{spread}; "
            f"probe minus shuffled {_fmt(s.probe_minus_shuffled, sign=True)}"
        )
    o = h.observer
    if o is not None:
        best = o.balanced_accuracy[o.layers.index(o.best_layer)]
        model = r.control.model_id if r.control else "control"
        lines.append(
            f"          control observer {model}: at its own best layer {o.source_layer}: "
            f"{_fmt(o.at_source_layer)}; on {r.target_suite}, {describe(o.best_layer, o.tied)}: {_fmt(best)}; "
            f"probe minus control (own layers) {_fmt(o.probe_minus_observer, sign=True)}, best minus best "
            f"{_fmt(o.best_minus_best, sign=True)} ({len(o.atoms)} atoms)"
        )
    return lines


def table_lines(r: CrossSuite) -> list[str]:
    """The result as text: per head, the best layer against the baselines, then the families."""
    lines = [
        f"probes {r.probes} ({r.source_suite}) on store {r.store} ({r.target_suite}): {r.episodes} episodes, "
        f"{r.rows} rows, balanced accuracy with 95% intervals over {r.resamples} episode resamples"
    ]
    for head, h in r.heads.items():
        i = h.layers.index(h.best_layer)
        best = h.balanced_accuracy[i]
        source = "–" if h.source is None else f"{h.source:.3f} ({h.source_split})"
        lines.append(
            f"  {head:>6}: {len(h.atoms)} shared atoms, {h.scored} scored; at the probes' own best layer "
            f"{h.source_layer}: {_fmt(h.at_source_layer)}; on {r.target_suite}, {describe(h.best_layer, h.tied)}: "
            f"{_fmt(best)}; majority {_fmt(h.majority)}; time (fit on {r.source_suite}) {_fmt(h.time)}; "
            f"best minus time {_fmt(h.best_minus_time, sign=True)}; on {r.source_suite} at layer {h.best_layer} "
            f"{source}"
        )
        lines.extend(_control_lines(r, h))
        for f in h.families:
            lines.append(f"          {f.family:<22} {f.atoms:>3} atoms  {_fmt(f.balanced_accuracy)}")
    for head, atoms in r.unshared.items():
        if atoms:
            lines.append(f"  {head:>6}: {len(atoms)} probed atoms absent from {r.target_suite} (not scored)")
    return lines
