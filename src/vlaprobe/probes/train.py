"""``vlaprobe train``: split, filter, train per-layer probes with controls, evaluate, save.

Reading order: :func:`train_probes` (store -> :class:`ProbeData`) calls :func:`train_on_data`, which runs
the experiment top to bottom; the helpers below it each do one step. Output folder:

- ``probes.safetensors`` + ``probes.json``: the probes (:class:`ProbeSet`), best layer per head included;
- ``evaluation.json`` (:class:`~vlaprobe.probes.results.Evaluation`): every metric per layer and atom /
  predicate / layer mean, with bootstrap intervals, for the probes, the majority baseline, the shuffled-label
  control (mean and spread over permutations), selectivity and the observer control;
- ``config.json``: the configuration, loadable with ``vlaprobe train --config``.
"""

from __future__ import annotations

import json
import logging
import math
import time
from pathlib import Path

import numpy as np
import torch

from vlaprobe.collection.store import read_meta
from vlaprobe.configs.checks import check_train
from vlaprobe.configs.env import same_suite
from vlaprobe.configs.train import TrainConfig
from vlaprobe.devices import resolve_device
from vlaprobe.errors import VlaprobeError
from vlaprobe.files import write_atomic
from vlaprobe.probes.bootstrap import bootstrap_weights
from vlaprobe.probes.conditional import conditional_fit
from vlaprobe.probes.data import ProbeData, load_store
from vlaprobe.probes.evaluate import CrossFit, column_groups, cross_fit, evaluate_head
from vlaprobe.probes.matched import Scored, add_within_cells
from vlaprobe.probes.observer_control import head_columns, observer_control, warn_c_at_edge
from vlaprobe.probes.outfolder import check_free_space, check_probe_folder, locked, replace_folder
from vlaprobe.probes.probeset import ProbeSet
from vlaprobe.probes.record import config_dict, evaluation_record, probe_meta
from vlaprobe.probes.results import (
    CONFIG_FILE,
    DroppedAtom,
    Evaluation,
    SkippedHead,
    read_evaluation,
    write_evaluation,
)
from vlaprobe.probes.split import (
    UNDEFINED,
    Fold,
    LabelFilter,
    check_no_leak,
    filter_labels,
    make_folds,
    rows_of,
)
from vlaprobe.probes.ties import describe
from vlaprobe.probes.trainer import LinearProbes, fit_probes

log = logging.getLogger("vlaprobe.probes")


def train_probes(cfg: TrainConfig) -> Path:
    """Train and evaluate probes on ``cfg.store``; return the output folder."""
    resolve_device(cfg.probe.device)  # a bad --probe.device fails before the store is read, not after
    check_train(cfg)
    out = cfg.out if cfg.out is not None else Path(cfg.store).parent / "probes"
    check_probe_folder(out)
    metas = [read_meta(Path(s)) for s in (cfg.store, cfg.observer_store) if s is not None]
    # (a mistyped store fails before the lock file is created beside --out)
    if cfg.observer_store is not None:
        same_folder = Path(cfg.observer_store).resolve() == Path(cfg.store).resolve()
        if same_folder or metas[0]["model_id"] == metas[1]["model_id"]:
            raise VlaprobeError(
                f"--observer-store {cfg.observer_store} holds the hidden states of the same model "
                f"({metas[0]['model_id']!r}) as --store {cfg.store}: the control would compare the probes with "
                "themselves; pass the store a second observer saw (e.g. control/activations of vlaprobe run)"
            )
        suites = [str(m.get("suite") or "libero_spatial") for m in metas]  # stores before suites: spatial's
        same_suite(f"--store {cfg.store}", suites[0], f"--observer-store {cfg.observer_store}", suites[1])
    with locked(out):
        data = load_store(cfg.store, heads=cfg.heads, layers=cfg.layers, success_only=cfg.split.success_only)
        observer = None
        if cfg.observer_store is not None:
            observer = load_store(
                cfg.observer_store, heads=cfg.heads, layers=cfg.layers, success_only=cfg.split.success_only
            )
        check_free_space(out, data)
        return train_on_data(data, cfg, out, observer=observer)


def main(cfg: TrainConfig) -> int:
    """CLI entry: train, then print where the probes are."""
    if not logging.getLogger().handlers and not log.handlers:
        logging.basicConfig(level=logging.INFO, format="%(message)s")
    out = train_probes(cfg)
    for head, h in read_evaluation(out).heads.items():
        best = h.best
        value = "undefined" if best.value is None else f"{best.value:.3f}"
        undefined = sum(d.reason.startswith(UNDEFINED) for d in h.dropped)
        note = f", {undefined} dropped as undefined (objects absent from the tasks)" if undefined else ""
        print(
            f"{head}: {len(h.atoms)} atoms probed{note}, {describe(best.layer, best.tied)} ({best.metric} {value})"
        )
    print(f"probes and evaluation written to {out}")
    return 0


def train_on_data(
    data: ProbeData, cfg: TrainConfig, out: str | Path, observer: ProbeData | None = None
) -> Path:
    """Run the whole experiment on in-memory data and write the output folder; return it."""
    started = time.perf_counter()
    seeds = {"split": cfg.seed, "probe": cfg.seed + 1, "shuffle": cfg.seed + 2, "bootstrap": cfg.seed + 3}
    heads = _check_heads(data, cfg)
    if cfg.shuffled_control and cfg.shuffled_permutations < 1:
        raise VlaprobeError(
            f"--shuffled-permutations must be at least 1 with the shuffled control, got "
            f"{cfg.shuffled_permutations} (or pass --no-shuffled-control)"
        )
    folds, fold_rows = _split_rows(data, cfg, seeds["split"])  # 1. by episode, leak-checked
    heads, filters, skipped_heads = _filter_atoms(data, cfg, heads, fold_rows)  # 2. atoms that vary
    columns = head_columns(heads, filters)
    targets = np.concatenate([data.labels[h][:, filters[h].kept] for h in heads], axis=1)
    defined = data.targets_defined({h: filters[h].kept for h in heads})  # None: all defined
    column_head = np.concatenate([np.full(len(filters[h].kept), i) for i, h in enumerate(heads)])
    fitted, probes = _fit(data, cfg, seeds, targets, fold_rows, column_head, defined)  # 3. probes, controls
    trained = time.perf_counter()
    if cfg.conditional:  # 3b. what the hidden states add beyond task and time
        log.info("conditional probing over the task and task x time baselines")
        fitted.conditional = conditional_fit(
            data.hidden,
            data.episode,
            data.episode_tasks,
            targets,
            fold_rows,
            cfg,
            fitted.fold_probes,
            defined,
        )
    conditioned = time.perf_counter()
    # 4. Evaluate everything on the same bootstrap resamples of test episodes.
    log.info("evaluating with %d bootstrap resamples of %d test episodes", cfg.bootstrap, fitted.num_groups)
    weights = bootstrap_weights(
        fitted.num_groups, max(cfg.bootstrap, cfg.auprc_bootstrap), seeds["bootstrap"]
    )
    threshold_logit = math.log(cfg.probe.threshold / (1 - cfg.probe.threshold))
    head_results = {
        h: evaluate_head(h, data, filters[h], columns[h], fitted, targets, weights, threshold_logit, cfg)
        for h in heads
    }
    warn_c_at_edge({h: r.fit for h, r in head_results.items()})
    observer_info, observed = None, None
    if observer is not None:
        log.info("observer control: %s", observer.model_id)
        observer_info, observed = observer_control(
            observer, data, heads, filters, folds, cfg, seeds, weights, threshold_logit, head_results
        )
    main = Scored(data, fitted, targets, weights[: cfg.bootstrap])
    add_within_cells(head_results, main, columns, threshold_logit, observed)  # 4b. matched steps, families
    # 5. Save: probes (JSON last: it marks a complete folder), evaluation, config.
    meta = probe_meta(data, cfg, seeds, heads, filters, head_results, len(folds) > 1)
    evaluation = evaluation_record(data, cfg, seeds, folds, fold_rows, fitted, head_results, observer_info)
    evaluation.skipped_heads = {
        h: SkippedHead(reason=r, dropped=[DroppedAtom(**d) for d in filters[h].dropped])
        for h, r in skipped_heads.items()
    }
    evaluation.seconds = {
        "train": round(trained - started, 2),
        "conditional": round(conditioned - trained, 2),
        "total": round(time.perf_counter() - started, 2),
    }
    return _save(Path(out), cfg, evaluation, ProbeSet(meta, _tensors(probes, heads, columns)))


# -- steps ----------------------------------------------------------------------------------------------


def _split_rows(
    data: ProbeData, cfg: TrainConfig, seed: int
) -> tuple[list[Fold], list[tuple[np.ndarray, np.ndarray]]]:
    """The folds and their (train, test) rows; the rows handed to the trainer are checked for leaks."""
    folds = _split(data, cfg, seed)
    fold_rows = [(rows_of(data.episode, f.train), rows_of(data.episode, f.test)) for f in folds]
    for train_rows, test_rows in fold_rows:
        check_no_leak(data.episode, train_rows, test_rows)
    return folds, fold_rows


def _filter_atoms(
    data: ProbeData, cfg: TrainConfig, heads: list[str], fold_rows: list[tuple[np.ndarray, np.ndarray]]
) -> tuple[list[str], dict[str, LabelFilter], dict[str, str]]:
    """Keep the atoms that vary in every training split (among the rows defining them) and that some held-out
    row defines; heads left without atoms are skipped."""
    held = np.concatenate([te for _, te in fold_rows])
    filters = {}
    for h in heads:
        mask = data.partly_defined(h)
        filters[h] = filter_labels(
            [data.labels[h][tr] for tr, _ in fold_rows],
            data.atom_names[h],
            cfg.min_frequency,
            cfg.max_frequency,
            None if mask is None else [mask[tr] for tr, _ in fold_rows],
            None if mask is None else mask[held],
        )
    skipped = {h: f"all {len(filters[h].dropped)} atoms dropped" for h in heads if not len(filters[h].kept)}
    heads = [h for h in heads if h not in skipped]
    if not heads:
        raise VlaprobeError(
            f"every atom is true in < {cfg.min_frequency:.0%} or > {cfg.max_frequency:.0%} of the "
            "training steps; collect more varied episodes or change --min-frequency/--max-frequency"
        )
    return heads, filters, skipped


def _fit(
    data: ProbeData,
    cfg: TrainConfig,
    seeds: dict[str, int],
    targets: np.ndarray,
    fold_rows: list[tuple[np.ndarray, np.ndarray]],
    column_head: np.ndarray,
    defined: np.ndarray | None = None,
) -> tuple[CrossFit, LinearProbes]:
    """Train (probes and shuffled-label control together), score the held-out steps; the probes to save."""
    log.info(
        "training %d layers x %d atoms on %d steps (%d fold(s))",
        len(data.layers),
        targets.shape[1],
        data.num_steps,
        len(fold_rows),
    )
    permutations = cfg.shuffled_permutations if cfg.shuffled_control else 0
    fitted = cross_fit(data, targets, fold_rows, cfg, seeds, permutations, column_head, defined)
    probes = fitted.probes
    if len(fold_rows) > 1:  # cross-validated figures; the saved probes learn from every episode
        groups = column_groups(data, column_head, 0, cfg.split.by == "leave-one-task-out")
        probes = fit_probes(
            data.hidden,
            targets,
            np.arange(data.num_steps),
            cfg.probe,
            seeds["probe"],
            groups,
            defined=defined,
        )
    for p in {id(fitted.probes): fitted.probes, id(probes): probes}.values():
        _warn_at_cap(p)
    return fitted, probes


def _warn_at_cap(probes: LinearProbes) -> None:
    """Warn about probes that stopped above the tolerance: at the iteration cap, or where no step lowered the
    objective any more (float32 round-off near the minimum; harmless when the gradient is near ``tol``)."""
    conv = probes.convergence
    if conv is None or conv.converged.all():
        return
    stopped = ~conv.converged
    at_cap = stopped & (conv.iterations >= conv.max_iter)
    stalled = stopped & ~at_cap
    if at_cap.any():
        log.warning(
            "%d of %d probes stopped at --probe.max-iter %d above the tolerance %g (largest gradient %.2g); "
            "raise --probe.max-iter",
            int(at_cap.sum()),
            stopped.size,
            conv.max_iter,
            conv.tol,
            float(conv.grad_norm[at_cap].max()),
        )
    if stalled.any():
        log.warning(
            "%d of %d probes stopped where no step lowered the objective, above the tolerance %g (largest "
            "gradient %.2g): float32 round-off near the minimum",
            int(stalled.sum()),
            stopped.size,
            conv.tol,
            float(conv.grad_norm[stalled].max()),
        )


def _tensors(
    probes: LinearProbes, heads: list[str], columns: dict[str, np.ndarray]
) -> dict[str, torch.Tensor]:
    """The saved tensors: per head its weight columns and, when standardised, its own copy of the statistics
    (safetensors refuses two names for one memory)."""
    tensors = {}
    for h in heads:
        cols = columns[h]
        tensors[f"{h}.weight"] = probes.weight[:, :, cols].contiguous()
        tensors[f"{h}.bias"] = probes.bias[:, cols].contiguous()
        if probes.mean is not None and probes.std is not None:
            tensors[f"{h}.mean"], tensors[f"{h}.std"] = probes.mean.clone(), probes.std.clone()
    return tensors


def _save(out: Path, cfg: TrainConfig, evaluation: Evaluation, probes: ProbeSet) -> Path:
    """Write the folder as one unit: a kill leaves the old folder or the new one, never a mix."""

    def write(folder: Path) -> None:
        write_atomic(folder / CONFIG_FILE, json.dumps(config_dict(cfg), indent=1) + "\n")
        write_evaluation(folder, evaluation)
        probes.tensors = {k: v.cpu() for k, v in probes.tensors.items()}
        probes.save(folder)

    return replace_folder(out, write)


def _split(data: ProbeData, cfg: TrainConfig, seed: int) -> list[Fold]:
    """The folds, or a one-line error when the episodes cannot give every fold test and training data."""
    n = len(data.episode_keys)
    if cfg.split.folds > n:
        raise VlaprobeError(
            f"--split.folds {cfg.split.folds} needs at least {cfg.split.folds} episodes, the store has {n}; "
            "lower --split.folds or collect more"
        )
    folds = make_folds(data.episode_tasks, cfg.split, seed)
    if any(not len(f.test) or not len(f.train) for f in folds):
        raise VlaprobeError(
            f"no task has 2 episodes ({n} episodes of {len(set(data.episode_tasks.tolist()))} tasks), so none "
            "can be held out for testing; collect at least 2 episodes of a task (--episodes-per-task 2)"
        )
    return folds


def _check_heads(data: ProbeData, cfg: TrainConfig) -> list[str]:
    missing = [h for h in cfg.heads if h not in data.labels]
    if missing or not cfg.heads:
        raise VlaprobeError(
            f"no label head(s) {missing or '(none given)'}; use --heads with some of {data.heads}"
        )
    return list(cfg.heads)
