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
same atoms on its own held-out episodes. Saved probes are applied by
:func:`~vlaprobe.probes.apply.apply_probes_to_rows`, scored by :mod:`vlaprobe.probes.metrics` and resampled by
:mod:`vlaprobe.probes.bootstrap`, as everywhere else.
"""

from __future__ import annotations

import json
import math
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from vlaprobe.configs.cross_suite import CrossSuiteConfig
from vlaprobe.configs.env import SUITES, SuiteName
from vlaprobe.errors import VlaprobeError
from vlaprobe.probes.bootstrap import Estimate, bootstrap_weights, interval
from vlaprobe.probes.cross_suite_result import (
    CrossSuite,
    FamilyFigure,
    HeadTransfer,
    default_path,
    table_lines,
    write_cross_suite,
)
from vlaprobe.probes.probeset import ProbeSet
from vlaprobe.probes.results import DECIMALS
from vlaprobe.symbols import HEADS

if TYPE_CHECKING:
    import torch


@dataclass(frozen=True)
class Labels:
    """One store's labels of the shared atoms: what the baselines are fit on or scored against."""

    truth: dict[str, np.ndarray]
    """Head -> bool (rows, shared atoms)."""
    defined: dict[str, np.ndarray]
    """Head -> bool (rows, shared atoms): the row's task defines the atom."""
    episode: np.ndarray
    """int (rows,): episode position of each row."""
    episode_tasks: np.ndarray


LEVEL = ("value", "low", "high")


def _num(x: float) -> float | None:
    """A float rounded as the evaluation's files round (:data:`~vlaprobe.probes.results.DECIMALS`), NaN -> None."""
    return None if not np.isfinite(x) else round(float(x), DECIMALS)


def _suite(name: str) -> SuiteName:
    if name not in SUITES:
        raise VlaprobeError(f"unknown suite {name!r} in a store or probe file; use one of {list(SUITES)}")
    return name


def check_pair(cfg: CrossSuiteConfig, probes: ProbeSet) -> dict[str, list[str]]:
    """Refuse a store the probes cannot be scored on (one line each); return head -> shared atoms."""
    from vlaprobe.collection.store import read_store_meta

    meta = read_store_meta(cfg.store)
    if meta.suite == probes.suite:
        raise VlaprobeError(
            f"the probes in {cfg.probes} and store {cfg.store} are both {meta.suite}: within one suite, train "
            f"and evaluate with vlaprobe train --store {cfg.store}; cross-suite needs a store of another suite"
        )
    shared = {
        h: [a for a in probes.atoms(h) if a in set(meta.atom_names.get(h, []))]
        for h in HEADS
        if h in probes.heads
    }
    if not any(shared.values()):
        raise VlaprobeError(
            f"no atom probed in {cfg.probes} ({probes.suite}) is in the vocabulary of store {cfg.store} "
            f"({meta.suite}): nothing to score; pick suites that share objects (e.g. libero_spatial and libero_goal)"
        )
    if meta.model_id != probes.model_id or meta.pooling != probes.pooling:
        raise VlaprobeError(
            f"store {cfg.store} was observed by model {meta.model_id!r} ({meta.pooling}), the probes in "
            f"{cfg.probes} read {probes.model_id!r} ({probes.pooling}): another network's hidden states mean "
            f"nothing to them; collect the {meta.suite} store with --model {probes.model_id} --pooling "
            f"{probes.pooling}"
        )
    if meta.hidden_size != probes.hidden_size:
        raise VlaprobeError(
            f"store {cfg.store} holds hidden states of size {meta.hidden_size}, the probes in {cfg.probes} read "
            f"{probes.hidden_size}; collect the store with the probes' model"
        )
    return {h: a for h, a in shared.items() if a}


def read_labels(
    path: Path, shared: dict[str, list[str]], assets: Path | None, success_only: bool = False
) -> Labels:
    """The labels of the shared atoms in every (successful) episode of a store, and where they are defined."""
    from vlaprobe.collection.store import ActivationStore
    from vlaprobe.collection.verify import require_intact
    from vlaprobe.envs.suite_vocabulary import tasks_defined

    store = ActivationStore.open(path)
    require_intact(path)
    episodes = store.episodes(success_only=success_only)
    if not episodes:
        raise VlaprobeError(f"store {path} has no complete episode; collect some")
    keys = [e.key for e in episodes]
    tasks = np.array([e.task for e in episodes], np.int64)
    episode = np.asarray(store.step_index(keys)[0], np.int64)
    truth, defined = {}, {}
    recorded = store.records_defined(keys)  # a union store says itself; older stores: from the BDDL scenes
    for head, atoms in shared.items():
        names = store.atom_names[head]
        cols = [names.index(a) for a in atoms]
        truth[head] = np.asarray(store.labels(head, keys), bool)[:, cols]
        defined[head] = (
            store.defined(head, keys)[:, cols]
            if recorded
            else tasks_defined(_suite(store.suite), atoms, tasks.tolist(), assets)[episode]
        )
    return Labels(truth, defined, episode, tasks)


def source_store(cfg: CrossSuiteConfig, probes: ProbeSet) -> Path:
    """The store the probes were trained on (``--source-store`` or the one ``probes.json`` names)."""
    from vlaprobe.collection.store import read_store_meta

    path = cfg.source_store or probes.meta.store
    if path is None or not Path(path).exists():
        where = (
            f"--source-store {path} does not exist"
            if cfg.source_store
            else f"{cfg.probes}/probes.json names {'no store' if path is None else f'{path}, absent here'}"
        )
        raise VlaprobeError(
            f"the time baseline is fit on the store the probes were trained on, and {where}; pass that store "
            "as --source-store"
        )
    meta = read_store_meta(path)
    if meta.suite != probes.suite or meta.model_id != probes.model_id:
        raise VlaprobeError(
            f"--source-store {path} is a {meta.suite} store of model {meta.model_id!r}, the probes in "
            f"{cfg.probes} were trained on {probes.suite} with {probes.model_id!r}; pass the store they were "
            "trained on"
        )
    return Path(path)


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


def _est(value: float, resampled: np.ndarray) -> Estimate:
    """A figure and its interval over the resamples, as the file keeps them (None: undefined)."""
    return Estimate(_num(value), *(_num(x) for x in interval(resampled)))


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
    return (_num(float(np.mean(defined))) if defined else None), how


def score_head(
    probes: ProbeSet, hidden: torch.Tensor, layers: list[int], head: str, atoms: list[str], target: Labels,
    source: Labels, weights: np.ndarray, probes_path: Path,
) -> HeadTransfer | None:  # fmt: skip
    """One head on the target store (``hidden``: its (layers, rows, hidden) states at ``layers``); None when no
    shared atom has both classes on its rows."""
    import torch

    from vlaprobe.probes.apply import apply_probes_to_rows
    from vlaprobe.probes.families import family_columns
    from vlaprobe.probes.metrics import confusion_by_group, count_metrics, layer_means, summarize
    from vlaprobe.probes.ties import layer_resamples, tie_set

    at = [probes.layers.index(layer) for layer in layers]
    cols = [probes.atoms(head).index(a) for a in atoms]
    t = {k: v for k, v in probes.tensors.items() if k.startswith(f"{head}.")}
    mean, std = t.get(f"{head}.mean"), t.get(f"{head}.std")
    logits = apply_probes_to_rows(
        hidden, t[f"{head}.weight"][at][:, :, cols], t[f"{head}.bias"][at][:, cols],
        None if mean is None else mean[at], None if std is None else std[at],
    )  # fmt: skip
    cut = math.log(probes.threshold / (1 - probes.threshold))
    truth, defined, n = target.truth[head], target.defined[head], len(target.episode_tasks)

    def balanced(pred: torch.Tensor) -> tuple[np.ndarray, np.ndarray]:
        counts = confusion_by_group(pred, truth, target.episode, n, defined)
        point, resampled = count_metrics(counts, weights)
        return point["balanced_accuracy"], resampled["balanced_accuracy"]

    point, resampled = balanced(logits > cut)
    scored = int((~np.isnan(point[0])).sum())
    if not scored:
        return None
    groups = family_columns(atoms)
    summary = summarize(point, resampled, list(groups.values()))
    curve, curve_res = summary["layer"], layer_resamples(point, resampled)
    best = int(np.nanargmax(curve["value"]))
    base = {}
    for name, pred in baseline_predictions(source, target, head).items():
        value, res = layer_means(*balanced(torch.from_numpy(pred)[None]))
        base[name] = (float(value[0]), res[:, 0])
    fam = summary["predicate"]
    source_value, how = source_figure(probes_path, head, atoms, layers[best])
    own = probes.best_layer(head)
    return HeadTransfer(
        atoms=atoms,
        scored=scored,
        masked_rows=int((~defined).sum()),
        layers=layers,
        balanced_accuracy=[_est(curve["value"][i], curve_res[:, i]) for i in range(len(layers))],
        best_layer=layers[best],
        tied=[layers[i] for i in tie_set(curve["value"], curve_res, best)],
        source_layer=own,
        at_source_layer=(
            _est(curve["value"][layers.index(own)], curve_res[:, layers.index(own)])
            if own in layers
            else Estimate(None, None, None)
        ),
        majority=_est(*base["majority"]),
        time=_est(*base["time"]),
        best_minus_time=_est(curve["value"][best] - base["time"][0], curve_res[:, best] - base["time"][1]),
        source=source_value,
        source_split=how,
        families=[
            FamilyFigure(f, int(fam["count"][best, k]), Estimate(*(_num(fam[x][best, k]) for x in LEVEL)))
            for k, f in enumerate(groups)
        ],
    )


def cross_suite(cfg: CrossSuiteConfig) -> CrossSuite:
    """Score the probes of ``cfg.probes`` on ``cfg.store`` (see the module docstring)."""
    from vlaprobe.collection.store import read_store_meta
    from vlaprobe.probes.data import load_store

    if cfg.bootstrap < 10:
        raise VlaprobeError(f"--bootstrap must be at least 10, got {cfg.bootstrap}")
    if cfg.seed < 0:
        raise VlaprobeError(f"--seed must be at least 0, got {cfg.seed}")
    probes = ProbeSet.load(cfg.probes)
    shared = check_pair(cfg, probes)
    src = source_store(cfg, probes)
    source = read_labels(src, shared, cfg.assets)
    target = read_labels(cfg.store, shared, cfg.assets, cfg.success_only)
    depth = read_store_meta(cfg.store).num_hidden_states
    layers = [layer for layer in probes.layers if layer < depth]  # the layers both have
    data = load_store(cfg.store, heads=list(shared), layers=layers, success_only=cfg.success_only)
    weights = bootstrap_weights(len(target.episode_tasks), cfg.bootstrap, cfg.seed)
    heads = {}
    for head, atoms in shared.items():
        h = score_head(probes, data.hidden, layers, head, atoms, target, source, weights, cfg.probes)
        if h is not None:
            heads[head] = h
    if not heads:
        raise VlaprobeError(
            f"no shared atom has both classes on the rows of store {cfg.store}: balanced accuracy is undefined; "
            "collect episodes in which the shared objects change state"
        )
    return CrossSuite(
        probes=str(cfg.probes), store=str(cfg.store), source_store=str(src), source_suite=probes.suite,
        target_suite=data.suite, model_id=probes.model_id, pooling=probes.pooling,
        episodes=len(target.episode_tasks), rows=len(target.episode), resamples=cfg.bootstrap, seed=cfg.seed,
        threshold=probes.threshold, heads=heads,
        unshared={h: [a for a in probes.atoms(h) if a not in shared.get(h, [])] for h in probes.heads},
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
