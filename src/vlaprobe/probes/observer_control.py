"""``vlaprobe train``'s observer control (the same atoms probed on a second observer's hidden states) and the
helpers it shares with :mod:`vlaprobe.probes.train`."""

from __future__ import annotations

import logging

import numpy as np

from vlaprobe.configs.train import TrainConfig
from vlaprobe.errors import VlaprobeError
from vlaprobe.probes.bootstrap import bootstrap_weights
from vlaprobe.probes.data import ProbeData
from vlaprobe.probes.evaluate import cross_fit, evaluate_head
from vlaprobe.probes.matched import Scored
from vlaprobe.probes.results import HeadResult, ObserverInfo, ProbeFit
from vlaprobe.probes.split import Fold, LabelFilter, check_no_leak, make_folds, rows_of

log = logging.getLogger("vlaprobe.probes")


def head_columns(heads: list[str], filters: dict[str, LabelFilter]) -> dict[str, np.ndarray]:
    """Column range of each head in the concatenated target matrix."""
    out, start = {}, 0
    for h in heads:
        out[h] = np.arange(start, start + len(filters[h].kept))
        start += len(filters[h].kept)
    return out


def warn_c_at_edge(fits: dict[str, ProbeFit | None]) -> None:
    """Warn, per head, when the cross-validated C sits at an end of its grid at some layer."""
    for head, fit in fits.items():
        message = None if fit is None else fit.edge_warning(head)
        if message:
            log.warning("%s", message)


def observer_control(
    observer: ProbeData,
    data: ProbeData,
    heads: list[str],
    filters: dict[str, LabelFilter],
    folds: list[Fold],
    cfg: TrainConfig,
    seeds: dict[str, int],
    weights: np.ndarray,
    threshold_logit: float,
    head_results: dict[str, HeadResult],
) -> tuple[ObserverInfo, Scored]:
    """Train and evaluate the same atoms on a second observer's hidden states; sets each head's ``observer``
    and returns the observer's held-out scores too."""
    for h in heads:
        if observer.atom_names.get(h) != data.atom_names[h]:
            raise VlaprobeError(
                f"observer store has other {h} atoms than the main store; collect both with the same vocabulary"
            )
    same_episodes = observer.episode_keys == data.episode_keys
    if not same_episodes:
        folds = make_folds(observer.episode_tasks, cfg.split, seeds["split"])
    fold_rows = [(rows_of(observer.episode, f.train), rows_of(observer.episode, f.test)) for f in folds]
    for train_rows, test_rows in fold_rows:
        check_no_leak(observer.episode, train_rows, test_rows)
    targets = np.concatenate([observer.labels[h][:, filters[h].kept] for h in heads], axis=1)
    column_head = np.concatenate([np.full(len(filters[h].kept), i) for i, h in enumerate(heads)])
    defined = observer.targets_defined({h: filters[h].kept for h in heads})
    fitted = cross_fit(observer, targets, fold_rows, cfg, seeds, 0, column_head, defined)
    obs_weights = (
        weights
        if fitted.num_groups == weights.shape[1]
        else bootstrap_weights(fitted.num_groups, weights.shape[0], seeds["bootstrap"])
    )
    columns = head_columns(heads, filters)
    for h in heads:
        r = evaluate_head(
            h, observer, filters[h], columns[h], fitted, targets, obs_weights, threshold_logit, cfg
        )
        warn_c_at_edge({f"{h} (observer {observer.model_id})": r.fit})
        head_results[h].observer = r.probe
        head_results[h].observer_best = r.best
    info = ObserverInfo(
        model_id=observer.model_id,
        pooling=observer.pooling,
        layers=list(observer.layers),
        same_episodes=same_episodes,
        steps=observer.num_steps,
        episodes=len(observer.episode_keys),
    )
    return info, Scored(observer, fitted, targets, obs_weights[: cfg.bootstrap])
