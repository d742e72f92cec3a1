"""Probes trained on one LIBERO suite scored on another suite's store (``vlaprobe cross-suite``).

The probes of a source suite (say LIBERO-spatial) read the hidden states of every episode of a target suite's
store (say LIBERO-goal), observed by the same model with the same pooling, over the atoms both vocabularies
name alike (``on(akita_black_bowl_1,plate_1)``, ``grasped(plate_1)``, ...) and the layers both have. No target
episode was seen in training, so every one is scored. An atom over an object or region a target task lacks is
undefined there (read from the task's BDDL scene) and left out of that task's rows, never scored as false.

Per head: the balanced accuracy per layer averaged over the shared atoms, with a 95% interval over resamples of
the target episodes; at the probes' own best layer (chosen on the source suite: the unbiased reading); the best
layer on the target and the layers tied with it (:mod:`vlaprobe.probes.ties`; chosen on the scored data, so
optimistic); the atom
families at the best layer; and what the probes must beat there: the majority (0.5 wherever defined) and the
time-only baseline (normalised-time decile -> majority) fit on the source store's rows. The task baselines
cannot transfer: the target's tasks are not the source's. Next to it, the source evaluation's figure over the
same atoms on its own held-out episodes. The controls (:mod:`vlaprobe.probes.cross_suite_controls`, :mod:`~vlaprobe.probes.cross_suite_observer`): probes fit on
the source rows with shuffled labels, and the control observer's probes on the target store it observed. Saved
probes are applied by
:func:`~vlaprobe.probes.apply.apply_probes_to_rows`, scored by :mod:`vlaprobe.probes.metrics` and resampled by
:mod:`vlaprobe.probes.bootstrap`, as everywhere else.
"""

from __future__ import annotations

import json
from dataclasses import asdict, replace
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from vlaprobe.configs.cross_suite import CrossSuiteConfig
from vlaprobe.errors import VlaprobeError
from vlaprobe.probes.bootstrap import Estimate, bootstrap_weights
from vlaprobe.probes.cross_suite_inputs import (
    Curve,
    Labels,
    check_pair,
    est,
    num,
    read_labels,
    saved_logits,
    source_store,
    target_of,
    threshold_logit,
)
from vlaprobe.probes.cross_suite_result import (
    CrossSuite,
    FamilyFigure,
    HeadTransfer,
    default_path,
    table_lines,
    write_cross_suite,
)
from vlaprobe.probes.probeset import ProbeSet

if TYPE_CHECKING:
    import torch

LEVEL = ("value", "low", "high")


def baseline_predictions(source: Labels, target: Labels, head: str) -> dict[str, np.ndarray]:
    """The majority and time baselines fit on every source row, predicting every target row (bool)."""
    from vlaprobe.probes.baselines import predict_baselines

    n_src = len(source.episode_tasks)
    labels = np.concatenate([source.truth[head], target.truth[head]])
    defined = np.concatenate([source.defined[head], target.defined[head]])
    episode = np.concatenate([source.episode, target.episode + n_src])
    tasks = np.concatenate([source.episode_tasks, target.episode_tasks + source.episode_tasks.max() + 1])
    rows = np.arange(len(labels))
    pred = predict_baselines(labels, episode, tasks, rows[: len(source.episode)], rows[len(source.episode) :],
                             defined=defined)  # fmt: skip
    return {name: pred[name] for name in ("majority", "time")}


def source_figure(probes: Path, head: str, atoms: list[str], layer: int) -> tuple[float | None, str]:
    """The source evaluation's mean balanced accuracy over ``atoms`` at ``layer`` on its held-out episodes, and
    how it held them out; (None, "") without an evaluation or a figure there."""
    from vlaprobe.probes.results import read_evaluation

    if not (probes / "evaluation.json").is_file():
        return None, ""
    ev = read_evaluation(probes)
    h = ev.heads.get(head)
    if h is None or layer not in ev.layers or "balanced_accuracy" not in h.probe:
        return None, ""
    split = ev.config.get("split")
    by = str(split.get("by", "episode")) if isinstance(split, dict) else "episode"
    how = by if ev.split.folds == 1 or by != "episode" else f"{ev.split.folds}-fold"
    row = h.probe["balanced_accuracy"].atom.value[ev.layers.index(layer)]
    assert isinstance(row, list)
    values = [row[h.atoms.index(a)] for a in atoms if a in h.atoms]
    defined = [float(v) for v in values if v is not None]
    return (num(float(np.mean(defined))) if defined else None), how


def score_head(
    probes: ProbeSet, hidden: torch.Tensor, layers: list[int], head: str, atoms: list[str], target: Labels,
    source: Labels, weights: np.ndarray, probes_path: Path,
) -> tuple[HeadTransfer, Curve] | None:  # fmt: skip
    """One head on the target store (``hidden``: its (layers, rows, hidden) states at ``layers``) and its
    per-atom curve; None when no shared atom has both classes on its rows."""
    import torch

    from vlaprobe.probes.families import family_columns
    from vlaprobe.probes.metrics import layer_means, summarize
    from vlaprobe.probes.ties import tie_set

    scorer = target_of(target, head, weights)
    curve = scorer.score(saved_logits(probes, hidden, layers, head, atoms) > threshold_logit(probes))
    scored = int((~np.isnan(curve.point[0])).sum())
    if not scored:
        return None
    groups = family_columns(atoms)
    fam = summarize(curve.point, curve.resampled, list(groups.values()))["predicate"]
    value, res = curve.layer()
    best = int(np.nanargmax(value))
    base = {}
    for name, pred in baseline_predictions(source, target, head).items():
        b = scorer.score(torch.from_numpy(pred)[None])
        b_value, b_res = layer_means(b.point, b.resampled)
        base[name] = (float(b_value[0]), b_res[:, 0])
    source_value, how = source_figure(probes_path, head, atoms, layers[best])
    own = probes.best_layer(head)
    at_own = (
        est(value[layers.index(own)], res[:, layers.index(own)])
        if own in layers
        else Estimate(None, None, None)
    )
    transfer = HeadTransfer(
        atoms=atoms,
        scored=scored,
        masked_rows=int((~scorer.defined).sum()),
        layers=layers,
        balanced_accuracy=[est(value[i], res[:, i]) for i in range(len(layers))],
        best_layer=layers[best],
        tied=[layers[i] for i in tie_set(value, res, best)],
        source_layer=own,
        at_source_layer=at_own,
        majority=est(*base["majority"]),
        time=est(*base["time"]),
        best_minus_time=est(value[best] - base["time"][0], res[:, best] - base["time"][1]),
        source=source_value,
        source_split=how,
        families=[
            FamilyFigure(f, int(fam["count"][best, k]), Estimate(*(num(fam[x][best, k]) for x in LEVEL)))
            for k, f in enumerate(groups)
        ],
    )
    return transfer, curve


def cross_suite(cfg: CrossSuiteConfig) -> CrossSuite:
    """Score the probes of ``cfg.probes`` on ``cfg.store`` (see the module docstring)."""
    from vlaprobe.collection.store import read_store_meta
    from vlaprobe.probes.cross_suite_controls import shuffled_control
    from vlaprobe.probes.cross_suite_observer import check_control, observer_control
    from vlaprobe.probes.data import load_store

    if cfg.bootstrap < 10:
        raise VlaprobeError(f"--bootstrap must be at least 10, got {cfg.bootstrap}")
    if cfg.seed < 0:
        raise VlaprobeError(f"--seed must be at least 0, got {cfg.seed}")
    if cfg.shuffled_control and cfg.shuffled_permutations < 1:
        raise VlaprobeError(
            f"--shuffled-permutations must be at least 1 with the shuffled control, got "
            f"{cfg.shuffled_permutations} (or pass --no-shuffled-control)"
        )
    probes = ProbeSet.load(cfg.probes)
    shared = check_pair(cfg, probes)
    control = check_control(cfg, probes) if cfg.control_probes is not None or cfg.control_store else None
    src = source_store(cfg, probes)
    source = read_labels(src, shared, cfg.assets)
    target = read_labels(cfg.store, shared, cfg.assets, cfg.success_only)
    depth = read_store_meta(cfg.store).num_hidden_states
    layers = [layer for layer in probes.layers if layer < depth]  # the layers both have
    data = load_store(cfg.store, heads=list(shared), layers=layers, success_only=cfg.success_only)
    weights = bootstrap_weights(len(target.episode_tasks), cfg.bootstrap, cfg.seed)
    scored = {}
    for head, atoms in shared.items():
        h = score_head(probes, data.hidden, layers, head, atoms, target, source, weights, cfg.probes)
        if h is not None:
            scored[head] = h
    if not scored:
        raise VlaprobeError(
            f"no shared atom has both classes on the rows of store {cfg.store}: balanced accuracy is undefined; "
            "collect episodes in which the shared objects change state"
        )
    heads = {h: transfer for h, (transfer, _) in scored.items()}
    shuffled_info = control_info = None
    if cfg.shuffled_control:
        shuffled_info, shuffled = shuffled_control(cfg, probes, src, scored, data.hidden, target, weights)
        heads = {h: replace(t, shuffled=shuffled.get(h, [])) for h, t in heads.items()}
    if control is not None:
        control_info, observed = observer_control(cfg, control, scored, target, weights)
        heads = {h: replace(t, observer=observed.get(h)) for h, t in heads.items()}
    return CrossSuite(
        probes=str(cfg.probes), store=str(cfg.store), source_store=str(src), source_suite=probes.suite,
        target_suite=data.suite, model_id=probes.model_id, pooling=probes.pooling,
        episodes=len(target.episode_tasks), rows=len(target.episode), resamples=cfg.bootstrap, seed=cfg.seed,
        threshold=probes.threshold, heads=heads,
        unshared={h: [a for a in probes.atoms(h) if a not in shared.get(h, [])] for h in probes.heads},
        shuffled=shuffled_info, control=control_info,
    )  # fmt: skip


def main(cfg: CrossSuiteConfig) -> int:
    result = cross_suite(cfg)
    path = write_cross_suite(cfg.out or default_path(cfg.probes, result.target_suite), result)
    if cfg.json:
        print(json.dumps(asdict(result)))
    else:
        print("\n".join(table_lines(result)))
        print(f"written to {path}")
    return 0
