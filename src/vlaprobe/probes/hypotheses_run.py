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
from pathlib import Path

import numpy as np
import torch

from vlaprobe.configs.hypotheses import HypothesesConfig
from vlaprobe.errors import VlaprobeError
from vlaprobe.files import write_atomic
from vlaprobe.probes.bootstrap import bootstrap_weights
from vlaprobe.probes.hypotheses import Hypotheses, LayerCurves, answer_hypotheses, curves_from_counts
from vlaprobe.probes.metrics import confusion_by_group

FILE = "hypotheses.json"


def read_json(path: Path) -> dict:
    """A JSON file of the probe folder (``hypotheses.json``, ``probes.json`` ...), or a one-line error."""
    try:
        return json.loads(path.read_text())
    except (OSError, ValueError):
        raise VlaprobeError(f"cannot read {path}; pass the --out folder of `vlaprobe train`") from None


def run_curves(
    probes: Path, store: Path | None, resamples: int | None = None, seed: int | None = None
) -> LayerCurves:
    """Balanced-accuracy curves of both heads on the probes' test episodes, with joint resamples: by default
    (None) the evaluation's (its bootstrap count and seed), else ``resamples`` drawn with ``seed``."""
    from vlaprobe.probes import ProbeSet
    from vlaprobe.probes.data import load_store

    meta, ev = read_json(probes / "probes.json"), read_json(probes / "evaluation.json")
    if ev["split"]["folds"] != 1:
        raise VlaprobeError(
            f"{probes} was trained with {ev['split']['folds']} folds, and its saved probes were refit on every "
            "episode; train with one train/test split (the default) for H1/H2"
        )
    resamples = int(ev["bootstrap"]["resamples"]) if resamples is None else resamples
    seed = int(ev["seeds"]["bootstrap"]) if seed is None else seed
    if resamples < 10:
        raise VlaprobeError(
            f"{resamples} bootstrap resamples are too few for H1/H2 (without --bootstrap: those of {probes}'s "
            "evaluation); pass --bootstrap 10 or more"
        )
    ps = ProbeSet.load(probes)
    if not {"object", "action"} <= set(ps.heads):
        raise VlaprobeError(f"H1/H2 need object and action probes; {probes} has {ps.heads}")
    store = store or Path(meta["config"]["store"])
    data = load_store(store, heads=("object", "action"), layers=ps.layers)
    test = [data.episode_keys.index(k) for k in ev["split"]["test_episodes"] if k in data.episode_keys]
    if len(test) != len(ev["split"]["test_episodes"]):
        raise VlaprobeError(
            f"{store} lacks test episodes of {probes}; pass the store it was trained on (--store)"
        )
    rows = np.flatnonzero(np.isin(data.episode, test))
    position = {e: i for i, e in enumerate(test)}
    episode = np.array([position[e] for e in data.episode[rows]])
    cut = math.log(ps.threshold / (1 - ps.threshold))
    counts = {}
    for head in ("object", "action"):
        cols = [data.atom_names[head].index(a) for a in ps.atoms(head)]
        labels = data.labels[head][rows][:, cols]
        preds = np.zeros((len(ps.layers), len(rows), len(cols)), dtype=bool)
        for i in range(len(ps.layers)):
            x = data.hidden[i][torch.as_tensor(rows)].float()
            mean, std = ps.tensors.get(f"{head}.mean"), ps.tensors.get(f"{head}.std")
            if mean is not None and std is not None:
                x = (x - mean[i]) / std[i]
            logits = x @ ps.tensors[f"{head}.weight"][i] + ps.tensors[f"{head}.bias"][i]
            preds[i] = (logits > cut).numpy()
        counts[head] = confusion_by_group(preds, labels, episode, len(test))
    return curves_from_counts(counts, ps.layers, bootstrap_weights(len(test), resamples, seed))


def hypotheses(cfg: HypothesesConfig) -> Hypotheses:
    """Compute and save ``hypotheses.json`` in the probe folder."""
    if cfg.bootstrap is not None and cfg.bootstrap < 10:
        raise VlaprobeError(f"--bootstrap must be at least 10, got {cfg.bootstrap}")
    result = answer_hypotheses(run_curves(Path(cfg.probes), cfg.store, cfg.bootstrap, cfg.seed))
    write_atomic(Path(cfg.probes) / FILE, json.dumps(result.as_dict(), indent=1).encode())
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
