"""The probes' C search with warm starts against the same search from the cold start, in one run.

Both fit what ``vlaprobe train`` fits per split: the probes of every kept atom plus 5 shuffled-label copies,
C chosen per layer and head by 3-fold episode-grouped cross-validation over the default grid (1e-4 ... 100),
then the final fit on all training rows (:func:`~vlaprobe.probes.trainer.fit_probes`). Warm
(``warm_start=True``, the default): each fold's fit at a C starts from its solution at the C before, the final
fit from the folds' mean at the chosen C; cold: every fit from w = 0, b = the log-odds. The same minimisers:
the bench prints how many (layer, head) choices of C differ, the largest difference of the held-out scores and
of the final probes' test balanced accuracy per layer, and the two times.

Data: ``VLAPROBE_BENCH_STORE`` (an activation store, e.g. ``runs/default/activations``; its first split as
``vlaprobe train`` makes it), else ``synthetic_data`` shaped like the default run's store (10 tasks x 3
episodes x 138 steps, 33 hidden states of size 64, 224 + 12 atoms). One torch thread.

    .venv/bin/python bench/c_search.py

Prints progress on stderr and one JSON line with the figures on stdout (``ratio``: cold / warm CPU seconds,
robust to other jobs on the machine with one thread; the wall times are printed too).
"""

from __future__ import annotations

import json
import os
import sys
import time
from typing import Any

import numpy as np
import torch

import quick
from vlaprobe.configs.train import ProbeConfig, SplitConfig
from vlaprobe.probes import lbfgs, regularization
from vlaprobe.probes.data import ProbeData, load_store, synthetic_data
from vlaprobe.probes.evaluate import column_groups
from vlaprobe.probes.metrics import metrics_from_counts
from vlaprobe.probes.split import filter_labels, make_folds, rows_of
from vlaprobe.probes.trainer import LinearProbes, fit_probes
from vlaprobe.symbols import HEADS

PERMUTATIONS = 5


def log(msg: str) -> None:
    print(msg, file=sys.stderr, flush=True)


def bench_data() -> tuple[ProbeData, str]:
    store = os.environ.get("VLAPROBE_BENCH_STORE")
    if store:
        return load_store(store, heads=HEADS), store
    data = synthetic_data(
        num_tasks=10, episodes_per_task=3, steps_per_episode=quick.size(138, 10), num_layers=quick.size(33, 2),
        hidden_size=64, num_object=224, num_action=12, constant_fraction=0.55, signal=1.0, label_noise=0.05,
        seed=0,
    )  # fmt: skip
    return data, "synthetic"


def balanced(probes: LinearProbes, data: ProbeData, y: np.ndarray, test: np.ndarray) -> np.ndarray:
    """(layers,) test balanced accuracy at threshold 0.5, mean over the atoms where it is defined."""
    pred = (probes.logits(data.hidden, test) > 0).numpy()  # (layers, rows, atoms)
    truth = y[test].astype(bool)[None]
    counts = np.stack([pred & truth, pred & ~truth, ~pred & truth, ~pred & ~truth], -1).sum(1)
    return np.nanmean(metrics_from_counts(counts.astype(float))["balanced_accuracy"], -1)


def per_c_calls(calls: list[tuple[float, int]], grid: int) -> dict[str, list[float]]:
    """CPU seconds and solver iterations of the search per C, summed over the folds (the search's calls run fold
    by fold, each over the ascending grid)."""
    per = np.array(calls, float).reshape(-1, grid, 2).sum(0)
    return {"seconds": [round(v, 2) for v in per[:, 0]], "iterations": [int(v) for v in per[:, 1]]}


def recording() -> list[tuple[float, int]]:
    """(CPU seconds, summed iterations) of every solver call of the C search, in order."""
    calls: list[tuple[float, int]] = []

    def fit(*args: Any, **kwargs: Any) -> tuple[torch.Tensor, torch.Tensor, lbfgs.Convergence]:
        start = time.process_time()
        w, b, conv = lbfgs.fit_logistic(*args, **kwargs)
        calls.append((time.process_time() - start, int(conv.iterations.sum())))
        return w, b, conv

    setattr(regularization, "fit_logistic", fit)  # noqa: B010 (the search's solver, timed)
    return calls


def main() -> None:
    torch.set_num_threads(1)
    data, source = bench_data()
    fold = make_folds(data.episode_tasks, SplitConfig(), seed=0)[0]
    train, test = rows_of(data.episode, fold.train), rows_of(data.episode, fold.test)
    y = np.concatenate([data.labels[h] for h in HEADS], 1)
    head = np.concatenate([np.full(data.labels[h].shape[1], i) for i, h in enumerate(HEADS)])
    kept = filter_labels([y[train]], [str(i) for i in range(y.shape[1])], 0.01, 0.99).kept
    y, head = y[:, kept], head[kept]
    rng = np.random.default_rng(2)
    blocks = [y]
    for _ in range(PERMUTATIONS):
        shuffled = np.zeros_like(y)
        shuffled[train] = y[rng.permutation(train)]
        blocks.append(shuffled)
    targets, groups = np.concatenate(blocks, 1), column_groups(data, head, PERMUTATIONS)
    size = {"source": source, "layers": len(data.layers), "hidden": int(data.hidden.shape[2])}
    size |= {
        "train_steps": len(train),
        "test_steps": len(test),
        "atoms": y.shape[1],
        "columns": targets.shape[1],
    }
    log(f"data {size}")
    fits, seconds, calls = {}, {}, {}
    grid = len(ProbeConfig().c_grid)
    for on in (False, True):
        log(f"{'warm' if on else 'cold'} search ...")
        calls[on] = recording()
        start, cpu = time.perf_counter(), time.process_time()
        fits[on] = fit_probes(
            data.hidden, targets, train, ProbeConfig(device="cpu"), 1, groups, warm_start=on
        )
        seconds[on] = (time.perf_counter() - start, time.process_time() - cpu)
        log(f"  {seconds[on][0]:.1f} s wall, {seconds[on][1]:.1f} s CPU")
    cold, warm = fits[False], fits[True]
    assert (
        cold.cv is not None
        and warm.cv is not None
        and cold.cv.score is not None
        and warm.cv.score is not None
    )
    assert cold.convergence is not None and warm.convergence is not None
    k = y.shape[1]
    ba_cold, ba_warm = (
        balanced(cold.columns(slice(0, k)), data, y, test),
        balanced(warm.columns(slice(0, k)), data, y, test),
    )
    result = {
        "size": size,
        "cold_cpu_seconds": round(seconds[False][1], 2),
        "warm_cpu_seconds": round(seconds[True][1], 2),
        "ratio": round(seconds[False][1] / seconds[True][1], 2),
        "cold_wall_seconds": round(seconds[False][0], 2),
        "warm_wall_seconds": round(seconds[True][0], 2),
        "c_choices": int(warm.cv.chosen.size),
        "c_choices_differing": int((warm.cv.chosen != cold.cv.chosen).sum()),
        "cv_score_max_difference": float(np.nanmax(np.abs(warm.cv.score - cold.cv.score))),
        "test_balanced_accuracy_max_difference": float(np.nanmax(np.abs(ba_warm - ba_cold))),
        "search_per_c_cold": per_c_calls(calls[False], grid),
        "search_per_c_warm": per_c_calls(calls[True], grid),
        "final_iterations_cold": int(cold.convergence.iterations.sum()),
        "final_iterations_warm": int(warm.convergence.iterations.sum()),
        "final_at_cap": [
            int((~p.convergence.converged).sum()) for p in (cold, warm) if p.convergence is not None
        ],
    }
    print(json.dumps(result))


if __name__ == "__main__":
    main()
