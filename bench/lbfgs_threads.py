"""The probes' solver on a CPU with two torch threads: layers side by side (one thread each, the default) against
one layer at a time with both threads splitting each operation, in one run.

``fit_logistic`` solves every layer's problems independently. A layer's operations (rows x columns of a few
hundred thousand entries, hidden size 64) are too small for torch to split well across threads, and the
solver's Python steps are serial; with the layers side by side, one thread each, one layer's Python steps
overlap the other's arithmetic. The same problems either way: the bench checks that the side-by-side fit equals a
one-thread fit bit for bit (the result no longer depends on the thread count) and prints both wall times and
their ratio (``speedup``: one layer at a time / side by side).

Data: ``synthetic_data`` shaped like the default run's store (10 tasks x 3 episodes x 138 steps, 33 hidden states
of size 64, 224 + 12 atoms), its kept atoms plus 5 shuffled-label copies at C = 1, as the final fit of
``vlaprobe train``.

    .venv/bin/python bench/lbfgs_threads.py
"""

from __future__ import annotations

import json
import sys
import time
from collections.abc import Callable

import numpy as np
import torch

import quick
from vlaprobe.probes import lbfgs
from vlaprobe.probes.data import synthetic_data
from vlaprobe.probes.split import filter_labels
from vlaprobe.probes.trainer import training_matrix
from vlaprobe.symbols import HEADS

PERMUTATIONS = 5
THREADS = 2


def problem() -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """(features (layers, rows, hidden) standardised, targets (rows, columns), l2 (layers, columns))."""
    data = synthetic_data(
        num_tasks=10, episodes_per_task=3, steps_per_episode=quick.size(138, 10), num_layers=quick.size(33, 2),
        hidden_size=64, num_object=224, num_action=12, constant_fraction=0.55, signal=1.0, label_noise=0.05,
        seed=0,
    )  # fmt: skip
    rows = np.arange(data.num_steps)
    y = np.concatenate([data.labels[h] for h in HEADS], 1)
    y = y[:, filter_labels([y], [str(i) for i in range(y.shape[1])], 0.01, 0.99).kept]
    rng = np.random.default_rng(2)
    y = np.concatenate([y] + [y[rng.permutation(rows)] for _ in range(PERMUTATIONS)], 1)
    x, _, _ = training_matrix(data.hidden, rows, torch.device("cpu"), standardize=True)
    l2 = torch.as_tensor(lbfgs.l2_of_c(np.ones((x.shape[0], y.shape[1])), len(rows)), dtype=torch.float32)
    return x, torch.as_tensor(y, dtype=torch.float32), l2


def timed(x: torch.Tensor, y: torch.Tensor, l2: torch.Tensor, threads: int) -> tuple[float, tuple]:
    torch.set_num_threads(threads)
    start = time.perf_counter()
    fit = lbfgs.fit_logistic(x, y, l2)
    return time.perf_counter() - start, fit


def main() -> None:
    x, y, l2 = problem()
    print(f"data: {tuple(x.shape)} features, {y.shape[1]} columns", file=sys.stderr)
    side, fit_side = timed(x, y, l2, THREADS)
    one_thread, fit_one = timed(x, y, l2, 1)
    parallel = lbfgs._for_each_part

    def one_at_a_time(parts: list[slice], solve: Callable[[slice], None], device: torch.device) -> None:
        for part in parts:
            solve(part)

    lbfgs._for_each_part = one_at_a_time  # the path before: each layer's operations split across the threads
    try:
        sequential, _ = timed(x, y, l2, THREADS)
    finally:
        lbfgs._for_each_part = parallel
    same = all(torch.equal(a, b) for a, b in zip(fit_side[:2], fit_one[:2], strict=True))
    result = {
        "layers": x.shape[0],
        "rows": x.shape[1],
        "columns": y.shape[1],
        "threads": THREADS,
        "side_by_side_s": round(side, 2),
        "one_layer_at_a_time_s": round(sequential, 2),
        "one_thread_s": round(one_thread, 2),
        "speedup": round(sequential / side, 2),
        "same_bits_as_one_thread": same,
        "iterations": int(fit_side[2].iterations.sum()),
    }
    print(json.dumps(result))


if __name__ == "__main__":
    main()
