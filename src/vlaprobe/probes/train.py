"""``vlaprobe train``: split, filter, train per-layer probes with controls, evaluate, save.

Reading order: :func:`train_probes` (store -> :class:`ProbeData`) calls :func:`train_on_data`, which runs
the experiment top to bottom; the helpers below it each do one step. Output folder:

- ``probes.safetensors`` + ``probes.json``: the probes (:class:`ProbeSet`), best layer per head included;
- ``evaluation.json``: every metric per layer and atom / predicate / layer mean, with bootstrap intervals,
  for the probes, the majority baseline, the shuffled-label control, selectivity and the observer control;
- ``config.json``: the configuration, loadable with ``vlaprobe train --config``.
"""

from __future__ import annotations

import json
import logging
import math
import time
from pathlib import Path
from typing import Any

import numpy as np
import torch

from vlaprobe.configs.train import TrainConfig
from vlaprobe.devices import resolve_device
from vlaprobe.errors import VlaprobeError
from vlaprobe.files import versions, write_atomic
from vlaprobe.probes.data import ACTION_PREDICATES, OBJECT_PREDICATES, ProbeData, load_store, predicate
from vlaprobe.probes.metrics import COUNT_METRICS, METRICS, atom_metrics, bootstrap_weights, summarize
from vlaprobe.probes.probeset import FORMAT, FORMAT_VERSION, ProbeSet
from vlaprobe.probes.split import LabelFilter, check_no_leak, filter_labels, rows_of, split_episodes
from vlaprobe.probes.trainer import LinearProbes, fit_probes

log = logging.getLogger("vlaprobe.probes")

EVALUATION_FILE = "evaluation.json"
CONFIG_FILE = "config.json"


def train_probes(cfg: TrainConfig) -> Path:
    """Train and evaluate probes on ``cfg.store``; return the output folder."""
    resolve_device(cfg.probe.device)  # a bad --probe.device fails before the store is read, not after
    data = load_store(cfg.store, heads=cfg.heads, layers=cfg.layers, success_only=cfg.split.success_only)
    observer = None
    if cfg.observer_store is not None:
        observer = load_store(
            cfg.observer_store, heads=cfg.heads, layers=cfg.layers, success_only=cfg.split.success_only
        )
    out = cfg.out if cfg.out is not None else Path(cfg.store).parent / "probes"
    return train_on_data(data, cfg, out, observer=observer)


def main(cfg: TrainConfig) -> int:
    """CLI entry: train, then print where the probes are."""
    if not logging.getLogger().handlers and not log.handlers:
        logging.basicConfig(level=logging.INFO, format="%(message)s")
    out = train_probes(cfg)
    summary = json.loads((out / EVALUATION_FILE).read_text())
    for head, h in summary["heads"].items():
        best = h["best"]
        print(
            f"{head}: {len(h['atoms'])} atoms probed, best layer {best['layer']} "
            f"({best['metric']} {best['value']:.3f})"
        )
    print(f"probes and evaluation written to {out}")
    return 0


def train_on_data(
    data: ProbeData, cfg: TrainConfig, out: str | Path, observer: ProbeData | None = None
) -> Path:
    """Run the whole experiment on in-memory data and write the output folder; return it."""
    out = Path(out)
    started = time.perf_counter()
    seeds = {"split": cfg.seed, "probe": cfg.seed + 1, "shuffle": cfg.seed + 2, "bootstrap": cfg.seed + 3}
    heads = _check_heads(data, cfg)

    # 1. Split by episode; the rows handed to the trainer are checked for leaks.
    folds = split_episodes(data.episode_tasks, cfg.split.test_fraction, cfg.split.folds, seeds["split"])
    fold_rows = [(rows_of(data.episode, f.train), rows_of(data.episode, f.test)) for f in folds]
    for train_rows, test_rows in fold_rows:
        check_no_leak(data.episode, train_rows, test_rows)

    # 2. Keep atoms that vary in every training split.
    filters = {
        h: filter_labels(
            [data.labels[h][tr] for tr, _ in fold_rows],
            data.atom_names[h],
            cfg.min_frequency,
            cfg.max_frequency,
        )
        for h in heads
    }
    skipped_heads = {
        h: f"all {len(filters[h].dropped)} atoms dropped" for h in heads if not len(filters[h].kept)
    }
    heads = [h for h in heads if h not in skipped_heads]
    if not heads:
        raise VlaprobeError(
            f"every atom is true in < {cfg.min_frequency:.0%} or > {cfg.max_frequency:.0%} of the "
            "training steps; collect more varied episodes or change --min-frequency/--max-frequency"
        )
    columns = _columns(heads, filters)
    targets = np.concatenate([data.labels[h][:, filters[h].kept] for h in heads], axis=1)

    # 3. Train (probes and shuffled-label control together) and score the held-out steps.
    log.info(
        "training %d layers x %d atoms on %d steps (%d fold(s))",
        len(data.layers),
        targets.shape[1],
        data.num_steps,
        len(folds),
    )
    fitted = _cross_fit(data, targets, fold_rows, cfg, seeds, control=cfg.shuffled_control)
    probes = fitted["probes"]
    if len(folds) > 1:  # cross-validated figures; the saved probes learn from every episode
        probes = fit_probes(data.hidden, targets, np.arange(data.num_steps), cfg.probe, seeds["probe"])
    trained = time.perf_counter()

    # 4. Evaluate everything on the same bootstrap resamples of test episodes.
    log.info(
        "evaluating with %d bootstrap resamples of %d test episodes", cfg.bootstrap, fitted["num_groups"]
    )
    weights = bootstrap_weights(
        fitted["num_groups"], max(cfg.bootstrap, cfg.auprc_bootstrap), seeds["bootstrap"]
    )
    threshold_logit = math.log(cfg.probe.threshold / (1 - cfg.probe.threshold))
    head_results = {}
    for h in heads:
        head_results[h] = _evaluate_head(
            h, data, filters[h], columns[h], fitted, targets, weights, threshold_logit, cfg
        )

    observer_info = None
    if observer is not None:
        log.info("observer control: %s", observer.model_id)
        observer_info = _observer(
            observer, data, heads, filters, folds, cfg, seeds, weights, threshold_logit, head_results
        )

    # 5. Save: probes (JSON last: it marks a complete folder), evaluation, config.
    meta = _probe_meta(data, cfg, seeds, heads, filters, head_results, len(folds) > 1)
    tensors = {}
    for h in heads:
        cols = columns[h]
        tensors[f"{h}.weight"] = probes.weight[:, :, cols].contiguous()
        tensors[f"{h}.bias"] = probes.bias[:, cols].contiguous()
        if probes.mean is not None and probes.std is not None:
            tensors[f"{h}.mean"], tensors[f"{h}.std"] = probes.mean, probes.std
    evaluation = _evaluation_json(
        data, cfg, seeds, heads, folds, fold_rows, fitted, head_results, observer_info
    )
    evaluation["skipped_heads"] = {
        h: {"reason": r, "dropped": filters[h].dropped} for h, r in skipped_heads.items()
    }
    evaluation["seconds"] = {
        "train": round(trained - started, 2),
        "total": round(time.perf_counter() - started, 2),
    }
    write_atomic(out / CONFIG_FILE, json.dumps(_config_dict(cfg), indent=1) + "\n")
    write_atomic(out / EVALUATION_FILE, json.dumps(evaluation, allow_nan=False) + "\n")
    ProbeSet(meta, {k: v.cpu() for k, v in tensors.items()}).save(out)
    return out


# -- steps ----------------------------------------------------------------------------------------------


def _check_heads(data: ProbeData, cfg: TrainConfig) -> list[str]:
    missing = [h for h in cfg.heads if h not in data.labels]
    if missing or not cfg.heads:
        raise VlaprobeError(
            f"no label head(s) {missing or '(none given)'}; use --heads with some of {data.heads}"
        )
    return list(cfg.heads)


def _columns(heads: list[str], filters: dict[str, LabelFilter]) -> dict[str, np.ndarray]:
    """Column range of each head in the concatenated target matrix."""
    out, start = {}, 0
    for h in heads:
        out[h] = np.arange(start, start + len(filters[h].kept))
        start += len(filters[h].kept)
    return out


def _cross_fit(
    data: ProbeData,
    targets: np.ndarray,
    fold_rows: list[tuple[np.ndarray, np.ndarray]],
    cfg: TrainConfig,
    seeds: dict[str, int],
    control: bool,
) -> dict[str, Any]:
    """Train on each fold's training rows, score its test rows; pool the scores over folds.

    With ``control``, every fold also trains probes on its training labels permuted across steps (a second
    block of columns in the same matmuls, so it costs only wider weights). Returns the held-out rows,
    logits (layers, rows, atoms), control logits, the majority-class prediction of each row's fold, the
    row's test episode as a group index, the atoms' training frequency (mean over folds) and the last
    fold's probes.
    """
    rng = np.random.default_rng(seeds["shuffle"])
    k = targets.shape[1]
    eval_rows = np.sort(np.concatenate([te for _, te in fold_rows]))
    logits = torch.empty((len(data.layers), len(eval_rows), k))
    control_logits = torch.empty_like(logits) if control else None
    majority = np.empty((len(eval_rows), k), bool)
    train_frequency = np.zeros(k)
    probes: LinearProbes | None = None
    for i, (train_rows, test_rows) in enumerate(fold_rows):
        y = targets
        if control:
            shuffled = np.zeros_like(targets)
            shuffled[train_rows] = targets[rng.permutation(train_rows)]
            y = np.concatenate([targets, shuffled], axis=1)
        fitted = fit_probes(data.hidden, y, train_rows, cfg.probe, seeds["probe"] + i)
        scores = fitted.logits(data.hidden, test_rows)
        at = np.searchsorted(eval_rows, test_rows)
        logits[:, at] = scores[:, :, :k]
        if control_logits is not None:
            control_logits[:, at] = scores[:, :, k:]
        frequency = targets[train_rows].mean(0)
        majority[at] = frequency >= 0.5
        train_frequency += frequency / len(fold_rows)
        probes = LinearProbes(fitted.weight[:, :, :k], fitted.bias[:, :k], fitted.mean, fitted.std)
    episodes, groups = np.unique(data.episode[eval_rows], return_inverse=True)
    return {
        "rows": eval_rows,
        "logits": logits,
        "control_logits": control_logits,
        "majority": majority,
        "groups": groups,
        "num_groups": len(episodes),
        "episodes": episodes,
        "probes": probes,
        "train_frequency": train_frequency,
    }


def predicate_order(atoms: list[str]) -> list[str]:
    """Predicates of ``atoms`` in the paper's figure order; unknown predicates follow, sorted."""
    present = {predicate(a) for a in atoms}
    known = [p for p in (*OBJECT_PREDICATES, *ACTION_PREDICATES) if p in present]
    return known + sorted(present - set(known))


def _evaluate_head(
    head: str,
    data: ProbeData,
    filt: LabelFilter,
    cols: np.ndarray,
    fitted: dict[str, Any],
    targets: np.ndarray,
    weights: np.ndarray,
    threshold_logit: float,
    cfg: TrainConfig,
) -> dict[str, Any]:
    """All metrics of one head: probes, majority baseline, shuffled control, selectivity, best layer."""
    atoms = [data.atom_names[head][j] for j in filt.kept]
    preds = predicate_order(atoms)
    groups = [np.array([i for i, a in enumerate(atoms) if predicate(a) == p]) for p in preds]
    truth = targets[fitted["rows"]][:, cols]
    g, ng = fitted["groups"], fitted["num_groups"]
    count_weights = weights[: cfg.bootstrap]

    def run(logits: torch.Tensor, auprc_resamples: int) -> tuple[dict, dict]:
        point, res = atom_metrics(logits, truth, g, ng, threshold_logit, weights, auprc_resamples)
        for m in COUNT_METRICS:
            res[m] = res[m][: len(count_weights)]
        return point, res

    point, res = run(fitted["logits"][:, :, cols], cfg.auprc_bootstrap)
    out: dict[str, Any] = {"atoms": atoms, "predicates": preds, "groups": groups}
    out["probe"] = {m: summarize(point[m], res[m], groups) for m in METRICS}
    baseline = torch.where(torch.as_tensor(fitted["majority"][:, cols]), 1.0, -1.0)[None] + threshold_logit
    b_point, b_res = run(baseline, 0)
    out["baseline"] = {m: summarize(b_point[m], b_res[m], groups) for m in METRICS}
    if fitted["control_logits"] is not None:
        c_point, c_res = run(fitted["control_logits"][:, :, cols], 0)
        out["control"] = {m: summarize(c_point[m], c_res[m], groups) for m in METRICS}
        out["selectivity"] = {
            m: summarize(point[m] - c_point[m], res[m] - c_res[m], groups) for m in COUNT_METRICS
        }
    out["best"] = _best_layer(out["probe"], data.layers, cfg.select_metric)
    removed = {predicate(a) for a in data.atom_names[head]} - set(preds)
    out["skipped_predicates"] = sorted(removed, key=lambda p: predicate_order([f"{p}()", *atoms]).index(p))
    out["dropped"] = filt.dropped
    out["train_frequency"] = fitted["train_frequency"][cols]
    out["test_frequency"] = truth.mean(0)
    return out


def _best_layer(summary: dict[str, Any], layers: list[int], metric: str) -> dict[str, Any]:
    """Layer with the highest mean ``metric`` over the head's atoms (first one on ties)."""
    values = summary[metric]["layer"]["value"]
    i = 0 if np.all(np.isnan(values)) else int(np.nanargmax(values))
    layer = summary[metric]["layer"]
    return {
        "layer": layers[i],
        "index": i,
        "metric": metric,
        "value": _num(layer["value"][i]),
        "low": _num(layer["low"][i]),
        "high": _num(layer["high"][i]),
        "rule": f"highest mean {metric} over the head's probed atoms on held-out episodes",
    }


def _observer(
    observer: ProbeData,
    data: ProbeData,
    heads: list[str],
    filters: dict[str, LabelFilter],
    folds: list,
    cfg: TrainConfig,
    seeds: dict[str, int],
    weights: np.ndarray,
    threshold_logit: float,
    head_results: dict[str, dict[str, Any]],
) -> dict[str, Any]:
    """Train and evaluate the same atoms on a second observer's hidden states; adds "observer" to each head."""
    for h in heads:
        if observer.atom_names.get(h) != data.atom_names[h]:
            raise VlaprobeError(
                f"observer store has other {h} atoms than the main store; collect both with the same vocabulary"
            )
    same_episodes = observer.episode_keys == data.episode_keys
    if not same_episodes:
        folds = split_episodes(
            observer.episode_tasks, cfg.split.test_fraction, cfg.split.folds, seeds["split"]
        )
    fold_rows = [(rows_of(observer.episode, f.train), rows_of(observer.episode, f.test)) for f in folds]
    for train_rows, test_rows in fold_rows:
        check_no_leak(observer.episode, train_rows, test_rows)
    targets = np.concatenate([observer.labels[h][:, filters[h].kept] for h in heads], axis=1)
    fitted = _cross_fit(observer, targets, fold_rows, cfg, seeds, control=False)
    obs_weights = (
        weights
        if fitted["num_groups"] == weights.shape[1]
        else bootstrap_weights(fitted["num_groups"], weights.shape[0], seeds["bootstrap"])
    )
    columns = _columns(heads, filters)
    for h in heads:
        r = _evaluate_head(
            h, observer, filters[h], columns[h], fitted, targets, obs_weights, threshold_logit, cfg
        )
        head_results[h]["observer"] = r["probe"]
        head_results[h]["observer_best"] = r["best"]
    return {
        "model_id": observer.model_id,
        "pooling": observer.pooling,
        "layers": observer.layers,
        "same_episodes": same_episodes,
        "steps": observer.num_steps,
        "episodes": len(observer.episode_keys),
    }


# -- output -----------------------------------------------------------------------------------------------


def _num(x: Any) -> float | None:
    x = float(x)
    return None if math.isnan(x) else round(x, 5)


def _json_array(x: np.ndarray) -> Any:
    """Nested lists with NaN -> null and floats rounded to 5 decimals (keeps the file small and valid)."""
    arr = np.asarray(x)
    if arr.dtype.kind in "iub":
        return arr.tolist()
    rounded = np.round(arr.astype(np.float64), 5)
    return np.where(np.isnan(rounded), None, rounded).tolist()


def _summary_json(summary: dict[str, dict[str, dict[str, np.ndarray]]]) -> dict[str, Any]:
    return {
        m: {level: {k: _json_array(v) for k, v in parts.items()} for level, parts in levels.items()}
        for m, levels in summary.items()
    }


def _config_dict(cfg: TrainConfig) -> dict[str, Any]:
    from vlaprobe.configs import config_to_dict

    return config_to_dict(cfg)


def _probe_meta(
    data: ProbeData,
    cfg: TrainConfig,
    seeds: dict[str, int],
    heads: list[str],
    filters: dict[str, LabelFilter],
    results: dict[str, dict[str, Any]],
    refit: bool,
) -> dict[str, Any]:
    return {
        "format": FORMAT,
        "format_version": FORMAT_VERSION,
        "model_id": data.model_id,
        "pooling": data.pooling,
        "hidden_size": data.hidden_size,
        "num_hidden_states": data.num_hidden_states,
        "layers": data.layers,
        "threshold": cfg.probe.threshold,
        "action_tokens": "mean over the 7 action-token positions"
        if data.pooling == "action_tokens"
        else None,
        "heads": {
            h: {
                "atom_names": data.atom_names[h],
                "kept": results[h]["atoms"],
                "kept_index": filters[h].kept.tolist(),
                "dropped": filters[h].dropped,
                "best_layer": results[h]["best"]["layer"],
                "best_metric": results[h]["best"]["metric"],
                "best_value": results[h]["best"]["value"],
                "best_rule": results[h]["best"]["rule"],
            }
            for h in heads
        },
        "standardized": cfg.probe.standardize,
        "trained_on": {
            "episodes": len(data.episode_keys),
            "steps": data.num_steps,
            "split": "all episodes (refit after k-fold)" if refit else "training split",
        },
        "config": _config_dict(cfg),
        "seeds": seeds,
        "versions": versions(),
        "created": time.strftime("%Y-%m-%dT%H:%M:%S%z"),
    }


def _evaluation_json(
    data: ProbeData,
    cfg: TrainConfig,
    seeds: dict[str, int],
    heads: list[str],
    folds: list,
    fold_rows: list,
    fitted: dict[str, Any],
    results: dict[str, dict[str, Any]],
    observer: dict[str, Any] | None,
) -> dict[str, Any]:
    tasks = {int(t): int((data.episode_tasks == t).sum()) for t in np.unique(data.episode_tasks)}
    split = {
        "unit": "episode",
        "stratified_by": "task",
        "folds": len(folds),
        "test_fraction": cfg.split.test_fraction if len(folds) == 1 else 1 / len(folds),
        "train": {
            "episodes": int(sum(len(f.train) for f in folds) / len(folds)),
            "steps": int(sum(len(tr) for tr, _ in fold_rows) / len(folds)),
        },
        "test": {
            "episodes": int(sum(len(f.test) for f in folds) / len(folds)),
            "steps": int(sum(len(te) for _, te in fold_rows) / len(folds)),
        },
        "test_episodes": [data.episode_keys[i] for i in fitted["episodes"]],
        "leak_check": "passed: no step of a test episode was among the training rows",
    }
    heads_json = {}
    for h in heads:
        r = results[h]
        entry: dict[str, Any] = {
            "atoms": r["atoms"],
            "predicates": r["predicates"],
            "predicate_atoms": {
                p: [r["atoms"][i] for i in g] for p, g in zip(r["predicates"], r["groups"], strict=True)
            },
            "skipped_predicates": r["skipped_predicates"],
            "dropped": r["dropped"],
            "train_frequency": _json_array(r["train_frequency"]),
            "test_frequency": _json_array(r["test_frequency"]),
            "best": r["best"],
        }
        for part in ("probe", "baseline", "control", "selectivity", "observer"):
            if part in r:
                entry[part] = _summary_json(r[part])
        if "observer_best" in r:
            entry["observer_best"] = r["observer_best"]
        heads_json[h] = entry
    return {
        "format": "vlaprobe-evaluation",
        "format_version": 1,
        "model_id": data.model_id,
        "pooling": data.pooling,
        "layers": data.layers,
        "hidden_size": data.hidden_size,
        "threshold": cfg.probe.threshold,
        "metrics": list(METRICS),
        "dataset": {"episodes": len(data.episode_keys), "steps": data.num_steps, "episodes_per_task": tasks},
        "split": split,
        "bootstrap": {
            "unit": "test episode",
            "interval": "95% percentile",
            "resamples": cfg.bootstrap,
            "auprc_resamples": cfg.auprc_bootstrap,
        },
        "controls": {"shuffled_labels": cfg.shuffled_control, "observer": observer},
        "heads": heads_json,
        "config": _config_dict(cfg),
        "seeds": seeds,
        "versions": versions(),
    }
