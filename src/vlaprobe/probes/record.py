"""What ``vlaprobe train`` records: the probes' metadata (``probes.json``) and the evaluation (``evaluation.json``)."""

from __future__ import annotations

import time

import numpy as np

from vlaprobe.configs.train import TrainConfig
from vlaprobe.files import JsonObject, versions
from vlaprobe.probes.data import ProbeData
from vlaprobe.probes.evaluate import CrossFit
from vlaprobe.probes.metrics import METRICS
from vlaprobe.probes.probemeta import HeadMeta, ProbesMeta, TrainedOn
from vlaprobe.probes.results import (
    BestLayer,
    Bootstrap,
    Controls,
    Dataset,
    DroppedAtom,
    Episodes,
    Evaluation,
    HeadResult,
    ObserverInfo,
    Split,
)
from vlaprobe.probes.split import Fold, LabelFilter


def config_dict(cfg: TrainConfig) -> JsonObject:
    from vlaprobe.configs import config_to_dict

    return config_to_dict(cfg)


def tied_layers(best: BestLayer) -> list[int]:
    """The layers tied with the best (``best.tied``), the best included; [best layer] when none is recorded."""
    return sorted({int(layer) for layer in best.tied} | {int(best.layer)})


def probe_meta(
    data: ProbeData,
    cfg: TrainConfig,
    seeds: dict[str, int],
    heads: list[str],
    filters: dict[str, LabelFilter],
    results: dict[str, HeadResult],
    refit: bool,
) -> ProbesMeta:
    """``probes.json`` of a training run (written with the probes by ``ProbeSet.save``)."""

    def head(h: str) -> HeadMeta:
        best, tied = results[h].best, tied_layers(results[h].best)
        return HeadMeta(
            atom_names=list(data.atom_names[h]),
            kept=list(results[h].atoms),
            kept_index=filters[h].kept.tolist(),
            dropped=[DroppedAtom(**d) for d in filters[h].dropped],
            best_layer=best.layer,
            best_metric=best.metric,
            best_value=best.value,
            best_rule=best.rule,
            tied_layers=tied,
            default_layer=min(tied),
        )

    return ProbesMeta(
        suite=data.suite,
        model_id=data.model_id,
        pooling=data.pooling,
        hidden_size=data.hidden_size,
        num_hidden_states=data.num_hidden_states,
        layers=list(data.layers),
        threshold=cfg.probe.threshold,
        action_tokens="mean over the 7 action-token positions" if data.pooling == "action_tokens" else None,
        heads={h: head(h) for h in heads},
        standardized=cfg.probe.standardize,
        trained_on=TrainedOn(
            episodes=len(data.episode_keys),
            steps=data.num_steps,
            split="all episodes (refit after k-fold)" if refit else "training split",
        ),
        config=config_dict(cfg),
        seeds=seeds,
        versions=versions(),
        created=time.strftime("%Y-%m-%dT%H:%M:%S%z"),
    )


def evaluation_record(
    data: ProbeData,
    cfg: TrainConfig,
    seeds: dict[str, int],
    folds: list[Fold],
    fold_rows: list[tuple[np.ndarray, np.ndarray]],
    fitted: CrossFit,
    results: dict[str, HeadResult],
    observer: ObserverInfo | None,
) -> Evaluation:
    tasks = {str(int(t)): int((data.episode_tasks == t).sum()) for t in np.unique(data.episode_tasks)}
    n = len(folds)
    test_episodes = sum(len(f.test) for f in folds) / n
    split = Split(
        unit="episode",
        stratified_by="task",
        folds=n,
        test_fraction=cfg.split.test_fraction if n == 1 else 1 / n,
        realized_test_fraction=round(test_episodes / len(data.episode_keys), 5),
        train=Episodes(
            episodes=int(sum(len(f.train) for f in folds) / n),
            steps=int(sum(len(tr) for tr, _ in fold_rows) / n),
        ),
        test=Episodes(episodes=int(test_episodes), steps=int(sum(len(te) for _, te in fold_rows) / n)),
        test_episodes=[data.episode_keys[i] for i in fitted.episodes],
        leak_check="passed: no step of a test episode was among the training rows",
    )
    permutations = cfg.shuffled_permutations if cfg.shuffled_control else 0
    return Evaluation(
        suite=data.suite,
        model_id=data.model_id,
        pooling=data.pooling,
        layers=list(data.layers),
        hidden_size=data.hidden_size,
        threshold=cfg.probe.threshold,
        metrics=list(METRICS),
        dataset=Dataset(episodes=len(data.episode_keys), steps=data.num_steps, episodes_per_task=tasks),
        split=split,
        bootstrap=Bootstrap(
            unit="test episode",
            interval="95% percentile",
            resamples=cfg.bootstrap,
            auprc_resamples=cfg.auprc_bootstrap,
            undefined=(
                "a resample lacking a class the test set has leaves an atom's balanced accuracy and F1 undefined "
                "in that resample (its own interval uses the resamples that define it; `defined` counts them); "
                "averages are over the atoms defined on the full test set, an atom undefined in a resample "
                "entering it with its full-test-set value"
            ),
        ),
        controls=Controls(
            shuffled_labels=cfg.shuffled_control, shuffled_permutations=permutations, observer=observer
        ),
        heads=results,
        config=config_dict(cfg),
        seeds=seeds,
        versions=versions(),
    )
