"""``vlaprobe hypotheses``: H1/H2 (``vlaprobe.probes.hypotheses``) on a trained probe folder and its store.

The saved probes predict every test episode's steps at every layer; per-episode confusion counts give the
balanced-accuracy curves and their joint bootstrap resamples, with the functions and (by default) the
resamples of ``vlaprobe train``: its bootstrap seed and count, read from ``evaluation.json``, so the curves
and their per-layer intervals are the evaluation's ``layer`` level. The result goes to ``hypotheses.json``
in the probe folder (the report's "H1 and H2" section reads it).
"""

from __future__ import annotations

import json
import math
from dataclasses import asdict
from pathlib import Path

import dacite
import numpy as np

from vlaprobe.configs.hypotheses import HypothesesConfig
from vlaprobe.errors import VlaprobeError
from vlaprobe.files import from_json, read_versioned, write_atomic
from vlaprobe.probes.bootstrap import bootstrap_weights
from vlaprobe.probes.hypotheses import Hypotheses, LayerCurves, answer_hypotheses, curves_from_counts
from vlaprobe.probes.metrics import confusion_by_group
from vlaprobe.symbols import HEADS

FILE = "hypotheses.json"
FORMAT = "vlaprobe-hypotheses"
FORMAT_VERSION = 1
"""Version 1: :class:`~vlaprobe.probes.hypotheses.Hypotheses` with ``format`` and ``format_version``; a file
without them (written before they existed) holds the same fields and is read as version 1."""


def write_hypotheses(folder: str | Path, result: Hypotheses) -> Path:
    """Write ``<folder>/hypotheses.json`` atomically; return its path."""
    path = Path(folder) / FILE
    data = {"format": FORMAT, "format_version": FORMAT_VERSION, **asdict(result)}
    write_atomic(path, json.dumps(data, indent=1) + "\n")
    return path


def read_hypotheses(folder: str | Path) -> Hypotheses:
    """Read ``<folder>/hypotheses.json``; a one-line error if it is missing, damaged or of an unknown version."""
    path = Path(folder) / FILE
    hint = "run vlaprobe hypotheses --probes on the folder again"
    data, _ = read_versioned(path, FORMAT, "hypotheses file", (FORMAT_VERSION,), hint, unversioned=1)
    data = {k: v for k, v in data.items() if k not in ("format", "format_version")}
    return from_json(Hypotheses, data, path, hint, dacite.Config(check_types=False, cast=[tuple]))


def run_curves(
    probes: Path, store: Path | None, resamples: int | None = None, seed: int | None = None
) -> LayerCurves:
    """Balanced-accuracy curves of both heads on the probes' test episodes, with joint resamples: by default
    (None) the evaluation's (its bootstrap count and seed), else ``resamples`` drawn with ``seed``."""
    from vlaprobe.configs.env import same_suite
    from vlaprobe.probes import ProbeSet
    from vlaprobe.probes.apply import apply_probes_to_rows
    from vlaprobe.probes.data import load_store
    from vlaprobe.probes.results import read_evaluation

    ev = read_evaluation(probes)
    if ev.split.folds != 1:
        raise VlaprobeError(
            f"{probes} was trained with {ev.split.folds} folds, and its saved probes were refit on every "
            "episode; train with one train/test split (the default) for H1/H2"
        )
    resamples = ev.bootstrap.resamples if resamples is None else resamples
    seed = ev.seeds["bootstrap"] if seed is None else seed
    if resamples < 10:
        raise VlaprobeError(
            f"{resamples} bootstrap resamples are too few for H1/H2 (without --bootstrap: those of {probes}'s "
            "evaluation); pass --bootstrap 10 or more"
        )
    ps = ProbeSet.load(probes)
    if not {"object", "action"} <= set(ps.heads):
        raise VlaprobeError(f"H1/H2 need object and action probes; {probes} has {ps.heads}")
    store = store or ps.meta.store
    if store is None:
        raise VlaprobeError(f"{probes}/probes.json does not name its store; pass --store")
    data = load_store(store, heads=HEADS, layers=ps.layers)
    same_suite(f"store {store}", data.suite, f"the probes in {probes}", ps.suite)
    test_keys = ev.split.test_episodes
    test = [data.episode_keys.index(k) for k in test_keys if k in data.episode_keys]
    if len(test) != len(test_keys):
        raise VlaprobeError(
            f"{store} lacks test episodes of {probes}; pass the store it was trained on (--store)"
        )
    rows = np.flatnonzero(np.isin(data.episode, test))
    check_same_store(probes, ps.model_id, ev.split.test.steps, store, data.model_id, len(rows))
    position = {e: i for i, e in enumerate(test)}
    episode = np.array([position[e] for e in data.episode[rows]])
    cut = math.log(ps.threshold / (1 - ps.threshold))
    counts = {}
    for head in HEADS:
        cols = [data.atom_names[head].index(a) for a in ps.atoms(head)]
        labels = data.labels[head][rows][:, cols]
        t = ps.tensors
        logits = apply_probes_to_rows(
            data.hidden,
            t[f"{head}.weight"],
            t[f"{head}.bias"],
            t.get(f"{head}.mean"),
            t.get(f"{head}.std"),
            rows,
        )
        preds = logits > cut  # the rule of evaluation.json's figures
        defined = data.defined_mask(head)[rows][:, cols]  # union stores: undefined entries count nowhere
        counts[head] = confusion_by_group(
            preds, labels, episode, len(test), None if defined.all() else defined
        )
    return curves_from_counts(counts, ps.layers, bootstrap_weights(len(test), resamples, seed))


def check_same_store(
    probes: Path, model_id: str, test_steps: int, store: Path, store_model: str, store_test_steps: int
) -> None:
    """Refuse a store the probes were not trained on: another model's hidden states, or test episodes of the
    same names whose steps differ from those the evaluation scored (another collection)."""
    if store_model != model_id:
        raise VlaprobeError(
            f"store {store} was observed by model {store_model!r}, the probes of {probes} by {model_id!r}: their "
            "verdicts would score the probes on another model's hidden states; pass the store they were trained "
            "on (--store)"
        )
    if store_test_steps != test_steps:
        raise VlaprobeError(
            f"the test episodes of {probes} hold {test_steps} steps in its evaluation but {store_test_steps} in "
            f"store {store}: another collection under the same episode names; pass the store the probes were "
            "trained on (--store)"
        )


def hypotheses(cfg: HypothesesConfig) -> Hypotheses:
    """Compute and save ``hypotheses.json`` in the probe folder."""
    if cfg.bootstrap is not None and cfg.bootstrap < 10:
        raise VlaprobeError(f"--bootstrap must be at least 10, got {cfg.bootstrap}")
    if cfg.seed is not None and cfg.seed < 0:
        raise VlaprobeError(f"--seed must be at least 0, got {cfg.seed}")
    result = answer_hypotheses(run_curves(Path(cfg.probes), cfg.store, cfg.bootstrap, cfg.seed))
    write_hypotheses(cfg.probes, result)
    return result


def tie_sentences(probes: Path) -> dict[str, str]:
    """Head -> "best layer 30, tied with 8-12, 27-32" from the probe folder's ``evaluation.json`` (the set of
    :mod:`vlaprobe.probes.ties`, computed on the same test-episode resamples as its intervals)."""
    from vlaprobe.probes.results import read_evaluation
    from vlaprobe.probes.ties import describe

    heads = read_evaluation(probes).heads
    return {head: describe(h.best.layer, h.best.tied or [h.best.layer]) for head, h in heads.items()}


def main(cfg: HypothesesConfig) -> int:
    result = hypotheses(cfg)
    if cfg.json:
        print(json.dumps(result.as_dict()))
    else:
        ties = tie_sentences(Path(cfg.probes))
        for head, h in result.heads.items():
            print(
                f"{head:>6}: best layer {h.best} {list(h.best_interval)} (balanced accuracy {h.best_value:.3f}, "
                f"95% {h.best_value_interval[0]:.3f}-{h.best_value_interval[1]:.3f}); earliest within it "
                f"{h.earliest} {list(h.earliest_interval)}; steepest rise {h.steepest} {list(h.steepest_interval)}"
            )
            if head in ties:
                print(f"{'':>6}  evaluation.json: {ties[head]} (paired bootstrap over the test episodes)")
        for v in result.verdicts:
            print(v.sentence)
    return 0
