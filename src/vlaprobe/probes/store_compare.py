"""Stores side by side (``vlaprobe compare-stores``): what the task and the time alone predict, and how diverse.

For each store, from its labels alone (no hidden state, no probe): the majority, task and task x time
baselines (``vlaprobe.probes.baselines``) on the split ``vlaprobe train`` would make (whole episodes,
stratified by task, the same seed and test fraction) over the atoms its label filter would keep, as the mean
balanced accuracy over those atoms with a 95% bootstrap interval over test episodes (averages over a fixed set
of atoms, as the probes' figures); and the store's diversity (``vlaprobe.collection.diversity``). Each later
store is compared with the first (the reference, e.g. the fixed-init store): the difference of every
baseline with an interval from independent resamples of both stores' test episodes.

With ``--probes DIR`` the comparison is also written to ``DIR/store_comparison.json``, where ``vlaprobe
report`` shows it as a section.
"""

from __future__ import annotations

import json
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

import numpy as np
import torch

from vlaprobe.configs.stores import CompareStoresConfig
from vlaprobe.errors import VlaprobeError
from vlaprobe.files import JsonObject, from_json, read_versioned, write_atomic
from vlaprobe.probes.baselines import BASELINES, predict_baselines
from vlaprobe.probes.bootstrap import Estimate, bootstrap_weights, interval
from vlaprobe.probes.metrics import atom_metrics, layer_means
from vlaprobe.probes.split import filter_labels, rows_of, split_episodes
from vlaprobe.symbols import HEADS

FILE = "store_comparison.json"


@dataclass(frozen=True)
class HeadFigures:
    """One label head of one store."""

    atoms: int
    """Atoms of the head."""
    kept: int
    """Atoms the label filter keeps (those the baselines are scored on)."""
    distinct_states: int
    """Distinct state vectors of the head over all rows."""
    varying_atoms: int
    """Atoms that change within at least one episode."""
    baselines: dict[str, Estimate]
    """Baseline name (majority, task, task_time) -> mean balanced accuracy over the kept atoms."""
    difference: dict[str, Estimate] | None
    """This store minus the reference store, per baseline (None for the reference itself)."""


@dataclass(frozen=True)
class StoreFigures:
    name: str
    path: str
    episodes: int
    rows: int
    test_episodes: int
    perturbed_episodes: int
    heads: dict[str, HeadFigures]


@dataclass(frozen=True)
class StoreComparison:
    """Every store's figures; the first store is the reference of the differences."""

    metric: str
    seed: int
    test_fraction: float
    resamples: int
    stores: list[StoreFigures]

    def as_dict(self) -> JsonObject:
        return asdict(self)


FORMAT = "vlaprobe-store-comparison"
FORMAT_VERSION = 1
"""Version 1: :class:`StoreComparison` with ``format`` and ``format_version``; a file without them (written
before they existed) holds the same fields and is read as version 1."""


def write_store_comparison(folder: str | Path, comparison: StoreComparison) -> Path:
    """Write ``<folder>/store_comparison.json`` atomically; return its path."""
    path = Path(folder) / FILE
    data = {"format": FORMAT, "format_version": FORMAT_VERSION, **comparison.as_dict()}
    write_atomic(path, json.dumps(data, indent=1) + "\n")
    return path


def read_store_comparison(folder: str | Path) -> StoreComparison:
    """Read ``<folder>/store_comparison.json``; a one-line error if it is missing, damaged or of an unknown
    version (a file without a version, written before versions, reads as version 1)."""
    path = Path(folder) / FILE
    hint = "run vlaprobe compare-stores --probes again"
    data, _ = read_versioned(path, FORMAT, "store comparison", (FORMAT_VERSION,), hint, unversioned=1)
    data = {k: v for k, v in data.items() if k not in ("format", "format_version")}
    return from_json(StoreComparison, data, path, hint)


def _none(x: float) -> float | None:
    return None if not np.isfinite(x) else float(x)


def baseline_scores(
    labels: np.ndarray,
    episode: np.ndarray,
    episode_tasks: np.ndarray,
    train_episodes: np.ndarray,
    test_episodes: np.ndarray,
    weights: np.ndarray,
    defined: np.ndarray | None = None,
) -> dict[str, tuple[float, np.ndarray]]:
    """Per baseline: (mean balanced accuracy over the atoms defined on the test set, its value in each resample
    of ``weights`` (resamples, test episodes)). ``labels`` are the kept atoms' (rows, atoms) bools; ``defined``
    (same shape, union stores) leaves the undefined entries out of the fits and the scores."""
    train, test = rows_of(episode, train_episodes), rows_of(episode, test_episodes)
    pred = predict_baselines(labels, episode, episode_tasks, train, test, defined=defined)
    held = None if defined is None else defined[test]
    group = np.searchsorted(test_episodes, episode[test])
    out = {}
    for name in BASELINES:
        logits = torch.from_numpy(np.where(pred[name], 1.0, -1.0)[None])  # the probes' scoring, at logit 0
        points, resamples = atom_metrics(
            logits, labels[test], group, len(test_episodes), 0.0, weights, 0, held
        )
        value, per_resample = layer_means(points["balanced_accuracy"], resamples["balanced_accuracy"])
        out[name] = (float(value[0]), per_resample[:, 0])
    return out


def _interval(x: np.ndarray) -> tuple[float | None, float | None]:
    """The bootstrap interval of ``x`` (resamples,), None where undefined (the file's convention)."""
    low, high = interval(x)
    return _none(low), _none(high)


def _store_scores(path: Path, cfg: CompareStoresConfig) -> tuple[dict[str, Any], dict[str, Any]]:
    """The figures of one store, and per head the baselines' resamples (for the differences)."""
    from vlaprobe.collection.diversity import store_diversity
    from vlaprobe.collection.store import ActivationStore
    from vlaprobe.collection.verify import require_intact

    store = ActivationStore.open(path)
    require_intact(path)
    episodes = store.episodes(success_only=cfg.success_only)
    keys = [e.key for e in episodes]
    tasks = np.array([e.task for e in episodes], np.int64)
    if len(keys) < 2:
        raise VlaprobeError(
            f"store {path} has {len(keys)} complete episode(s); the baselines need at least 2"
        )
    (fold,) = split_episodes(tasks, cfg.test_fraction, 1, cfg.seed)
    if not len(fold.test):
        raise VlaprobeError(
            f"store {path}: no task has 2 episodes, so none is held out; collect at least 2 of a task"
        )
    position, _ = store.step_index(keys)
    episode = np.asarray(position, np.int64)
    weights = bootstrap_weights(len(fold.test), cfg.bootstrap, cfg.seed + 3)
    diversity = store_diversity(path, success_only=cfg.success_only)
    heads, resamples = {}, {}
    for head in HEADS:
        names = list(store.atom_names[head])
        labels = np.asarray(store.labels(head, keys), bool)
        mask = store.defined(head, keys) if store.records_defined(keys) else None
        train, test = rows_of(episode, fold.train), rows_of(episode, fold.test)
        kept = filter_labels(
            labels[train],
            names,
            cfg.min_frequency,
            cfg.max_frequency,
            None if mask is None else mask[train],
            None if mask is None else mask[test],
        ).kept
        held = None if mask is None else mask[:, kept]
        scores = baseline_scores(labels[:, kept], episode, tasks, fold.train, fold.test, weights, held)
        resamples[head] = {b: r for b, (_, r) in scores.items()}
        d = diversity.heads[head]
        heads[head] = {
            "atoms": len(names),
            "kept": len(kept),
            "distinct_states": d.distinct_states,
            "varying_atoms": d.varying,
            "baselines": {b: Estimate(_none(v), *_interval(r)) for b, (v, r) in scores.items()},
        }
    info = {
        "path": str(path),
        "episodes": len(keys),
        "rows": len(episode),
        "test_episodes": len(fold.test),
        "perturbed_episodes": diversity.perturbed_episodes,
        "heads": heads,
    }
    return info, resamples


def compare_stores(cfg: CompareStoresConfig) -> StoreComparison:
    """Every store's baselines and diversity, and each one's differences to the first."""
    stores = [Path(s) for s in cfg.stores]
    if len(stores) < 2:
        raise VlaprobeError("compare-stores needs at least 2 stores: the reference first, then the others")
    if cfg.names and len(cfg.names) != len(stores):
        raise VlaprobeError(
            f"--names gives {len(cfg.names)} names for {len(stores)} stores; give one per store"
        )
    if cfg.bootstrap < 10:
        raise VlaprobeError(f"--bootstrap must be at least 10, got {cfg.bootstrap}")
    if cfg.seed < 0:
        raise VlaprobeError(f"--seed must be at least 0, got {cfg.seed}")
    if not 0 < cfg.test_fraction < 1:
        raise VlaprobeError(f"--test-fraction must be between 0 and 1 (exclusive), got {cfg.test_fraction}")
    twice = [str(s) for i, s in enumerate(stores) if s.resolve() in {t.resolve() for t in stores[:i]}]
    if twice:
        raise VlaprobeError(
            f"store {twice[0]} is given twice: it would be compared with itself; pass each store once"
        )
    for s in stores:
        if not (s / "zarr.json").is_file():
            raise VlaprobeError(
                f"{s} is not an activation store (no zarr.json); pass folders of vlaprobe collect"
            )
    scored = [_store_scores(s, cfg) for s in stores]
    ref_info, ref_res = scored[0]
    figures = []
    for i, (info, res) in enumerate(scored):
        heads = {}
        for head, h in info["heads"].items():
            diff = None
            if i:
                diff = {}
                for b in BASELINES:
                    value = _sub(h["baselines"][b].value, ref_info["heads"][head]["baselines"][b].value)
                    diff[b] = Estimate(value, *_interval(res[head][b] - ref_res[head][b]))
            heads[head] = HeadFigures(**h, difference=diff)
        name = cfg.names[i] if cfg.names else stores[i].parent.name or str(stores[i])
        figures.append(StoreFigures(name=name, **{**info, "heads": heads}))
    return StoreComparison("balanced_accuracy", cfg.seed, cfg.test_fraction, cfg.bootstrap, figures)


def _sub(a: float | None, b: float | None) -> float | None:
    return None if a is None or b is None else a - b


def _fmt(e: Estimate, sign: bool = False) -> str:
    if e.value is None:
        return "–"
    spec = "+.3f" if sign else ".3f"
    if e.low is None or e.high is None:
        return format(e.value, spec)
    return f"{format(e.value, spec)} [{format(e.low, spec)}, {format(e.high, spec)}]"


def table_lines(c: StoreComparison) -> list[str]:
    """The comparison as text, one line per store and head (``vlaprobe compare-stores``)."""
    lines = []
    for s in c.stores:
        lines.append(
            f"{s.name}: {s.path}, {s.episodes} episodes ({s.test_episodes} test), {s.rows} rows, "
            f"{s.perturbed_episodes} perturbed"
        )
        for head, h in s.heads.items():
            base = "; ".join(f"{b} {_fmt(h.baselines[b])}" for b in BASELINES)
            lines.append(
                f"  {head:>6}: {h.distinct_states} distinct state vectors, {h.varying_atoms} of {h.atoms} atoms "
                f"change within an episode; balanced accuracy over {h.kept} kept atoms: {base}"
            )
            if h.difference is not None:
                diff = "; ".join(f"{b} {_fmt(h.difference[b], sign=True)}" for b in BASELINES)
                lines.append(f"          minus {c.stores[0].name}: {diff}")
    return lines


def main(cfg: CompareStoresConfig) -> int:
    if cfg.probes is not None:
        from vlaprobe.probes.probemeta import read_probes_meta

        read_probes_meta(cfg.probes)  # a probe folder, refused before the stores are read
    result = compare_stores(cfg)
    if cfg.probes is not None:
        write_store_comparison(cfg.probes, result)
    if cfg.json:
        print(json.dumps(result.as_dict()))
    else:
        print("\n".join(table_lines(result)))
    return 0
