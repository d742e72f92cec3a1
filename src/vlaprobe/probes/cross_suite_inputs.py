"""What ``vlaprobe cross-suite`` reads and how it scores: the pair check, the labels of the shared atoms, saved
probes applied to a store's rows, and the balanced accuracy of their predictions on the target's episodes.

Shared by the probes' own figures (:mod:`vlaprobe.probes.cross_suite`) and the controls
(:mod:`vlaprobe.probes.cross_suite_controls`), so both are scored by one scorer on the same resamples.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from vlaprobe.configs.cross_suite import CrossSuiteConfig
from vlaprobe.configs.env import SUITES, SuiteName
from vlaprobe.errors import VlaprobeError
from vlaprobe.probes.bootstrap import Estimate, interval, nan_mean
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
    keys: list[str]
    """The episodes' keys, in row order."""


@dataclass(frozen=True)
class Curve:
    """One predictor's balanced accuracy on the target rows: ``point`` (layers, atoms) and ``resampled``
    (resamples, layers, atoms) over the target's episode resamples."""

    point: np.ndarray
    resampled: np.ndarray

    def columns(self, cols: list[int]) -> Curve:
        return Curve(self.point[:, cols], self.resampled[:, :, cols])

    def layer(self) -> tuple[np.ndarray, np.ndarray]:
        """The mean over the atoms per layer (layers,) and in each resample (resamples, layers)."""
        from vlaprobe.probes.ties import layer_resamples

        return nan_mean(self.point, 1), layer_resamples(self.point, self.resampled)


@dataclass(frozen=True)
class Target:
    """One head's target rows and the resample weights of the target's episodes: the one scorer."""

    truth: np.ndarray
    defined: np.ndarray
    episode: np.ndarray
    episodes: int
    weights: np.ndarray

    def score(self, pred: torch.Tensor) -> Curve:
        """The balanced accuracy of ``pred`` (layers, rows, atoms) bool."""
        from vlaprobe.probes.metrics import confusion_by_group, count_metrics

        counts = confusion_by_group(pred, self.truth, self.episode, self.episodes, self.defined)
        point, resampled = count_metrics(counts, self.weights)
        return Curve(point["balanced_accuracy"], resampled["balanced_accuracy"])


def target_of(labels: Labels, head: str, weights: np.ndarray) -> Target:
    return Target(
        labels.truth[head], labels.defined[head], labels.episode, len(labels.episode_tasks), weights
    )


def num(x: float) -> float | None:
    """A float rounded as the evaluation's files round (:data:`~vlaprobe.probes.results.DECIMALS`), NaN -> None."""
    return None if not np.isfinite(x) else round(float(x), DECIMALS)


def est(value: float, resampled: np.ndarray) -> Estimate:
    """A figure and its interval over the resamples, as the file keeps them (None: undefined)."""
    return Estimate(num(value), *(num(x) for x in interval(resampled)))


def threshold_logit(probes: ProbeSet) -> float:
    return math.log(probes.threshold / (1 - probes.threshold))


def saved_logits(
    probes: ProbeSet, hidden: torch.Tensor, layers: list[int], head: str, atoms: list[str]
) -> torch.Tensor:
    """Logits (layers, rows, atoms) of the saved probes of ``head`` at ``layers`` on ``hidden`` (those layers'
    states, (layers, rows, hidden)), through :func:`~vlaprobe.probes.apply.apply_probes_to_rows`."""
    from vlaprobe.probes.apply import apply_probes_to_rows

    at = [probes.layers.index(layer) for layer in layers]
    cols = [probes.atoms(head).index(a) for a in atoms]
    t = probes.tensors
    mean, std = t.get(f"{head}.mean"), t.get(f"{head}.std")
    return apply_probes_to_rows(
        hidden, t[f"{head}.weight"][at][:, :, cols], t[f"{head}.bias"][at][:, cols],
        None if mean is None else mean[at], None if std is None else std[at],
    )  # fmt: skip


def suite_name(name: str) -> SuiteName:
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
            else tasks_defined(suite_name(store.suite), atoms, tasks.tolist(), assets)[episode]
        )
    return Labels(truth, defined, episode, tasks, keys)


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


UNDEFINED = Estimate(None, None, None)


def at_layer(curve: tuple[np.ndarray, np.ndarray], layers: list[int], layer: int) -> tuple[float, np.ndarray]:
    """A layer curve's value and resamples at ``layer`` (NaN where the curve lacks it)."""
    value, res = curve
    if layer not in layers:
        return float("nan"), np.full(res.shape[0], np.nan)
    i = layers.index(layer)
    return float(value[i]), res[:, i]


def difference(a: tuple[float, np.ndarray], b: tuple[float, np.ndarray]) -> Estimate:
    """``a - b`` paired over the same resamples (undefined where either is)."""
    if not (np.isfinite(a[0]) and np.isfinite(b[0])):
        return UNDEFINED
    return est(a[0] - b[0], a[1] - b[1])
