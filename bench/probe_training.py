"""Our batched probe trainer against scikit-learn's LogisticRegression, same data, same C, in one run.

Both fit the same L2-regularised logistic regression per (layer, atom) on the same standardised features
(training-split statistics) and the same C: ours all layers and atoms at once (batched L-BFGS to a gradient
tolerance), scikit-learn one ``LogisticRegression(C, lbfgs)`` per atom and layer (its default tolerance),
timed on ``--reference-layers`` layers and reported per layer. Both are scored on the same held-out episodes
(accuracy and balanced accuracy at threshold 0.5, mean over the reference layers' atoms). Also timed: our
default fit, which first chooses C per layer by 3-fold episode-grouped cross-validation over a 3-value grid.

Data: ``synthetic_data`` with the paper's shape: 10 tasks x 16 episodes x 50 steps = 8,000 steps, 33 hidden
states, 224 object + 12 action atoms of which about 100 survive the 1%/99% filter; hidden size 256 by default
so that scikit-learn finishes in a few minutes on 2 cores (``--hidden 4096`` for OpenVLA's).

    .venv/bin/python bench/probe_training.py [--hidden 256] [--reference-layers 2] [--threads 1]

Prints progress on stderr and one JSON line with the figures on stdout (target: speedup >= 10).
"""

from __future__ import annotations

import argparse
import json
import sys
import time

import numpy as np
import torch

import quick
from vlaprobe.configs.train import ProbeConfig
from vlaprobe.probes.data import synthetic_data
from vlaprobe.probes.evaluate import column_groups
from vlaprobe.probes.metrics import metrics_from_counts
from vlaprobe.probes.split import filter_labels, rows_of, split_episodes
from vlaprobe.probes.trainer import fit_probes
from vlaprobe.symbols import HEADS

C = 1.0


def log(msg: str) -> None:
    print(msg, file=sys.stderr, flush=True)


def scores(pred: np.ndarray, truth: np.ndarray) -> tuple[float, float]:
    """(accuracy, balanced accuracy) averaged over atoms."""
    counts = np.stack([(pred & truth), (pred & ~truth), (~pred & truth), (~pred & ~truth)], -1).sum(0)
    m = metrics_from_counts(counts.astype(float))
    return float(np.nanmean(m["accuracy"])), float(np.nanmean(m["balanced_accuracy"]))


def reference(x: np.ndarray, y: np.ndarray, train: np.ndarray, test: np.ndarray) -> tuple[float, np.ndarray]:
    """scikit-learn on one layer: (seconds, test predictions (rows, atoms))."""
    from sklearn.linear_model import LogisticRegression

    start = time.perf_counter()
    pred = np.zeros((len(test), y.shape[1]), bool)
    for j in range(y.shape[1]):
        model = LogisticRegression(C=C).fit(x[train], y[train, j])
        pred[:, j] = model.predict(x[test]).astype(bool)
    return time.perf_counter() - start, pred


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--hidden", type=int, default=quick.size(256, 16), help="hidden size")
    parser.add_argument(
        "--reference-layers", type=int, default=quick.size(2, 1), help="layers scikit-learn is timed on"
    )
    parser.add_argument("--threads", type=int, default=1, help="torch (and BLAS) threads for every part")
    args = parser.parse_args()
    torch.set_num_threads(args.threads)
    data = synthetic_data(
        num_tasks=10, episodes_per_task=quick.size(16, 3), steps_per_episode=quick.size(50, 10), num_layers=33, hidden_size=args.hidden,
        num_object=224, num_action=12, constant_fraction=0.55, signal=3.0, label_noise=0.0, seed=0,
    )  # fmt: skip
    fold = split_episodes(data.episode_tasks, test_fraction=0.2, folds=1, seed=0)[0]
    train, test = rows_of(data.episode, fold.train), rows_of(data.episode, fold.test)
    y = np.concatenate([data.labels[h] for h in HEADS], 1)
    y = y[:, filter_labels(y[train], [str(i) for i in range(y.shape[1])], 0.01, 0.99).kept]
    size = {"steps": data.num_steps, "layers": 33, "hidden": args.hidden, "train_steps": len(train)}
    size |= {"test_steps": len(test), "kept_labels": y.shape[1], "threads": args.threads}
    cfg = ProbeConfig(device="cpu")
    log(f"data {size}; our trainer, C = {C} ...")
    start = time.perf_counter()
    probes = fit_probes(data.hidden, y, train, cfg, seed=0, c=C)
    ours = time.perf_counter() - start
    assert probes.mean is not None and probes.std is not None and probes.convergence is not None
    log(f"ours: {ours:.1f}s for 33 layers; with cross-validated C ...")
    start = time.perf_counter()
    fit_probes(data.hidden, y, train, cfg, seed=0, groups=column_groups(data, np.zeros(y.shape[1], int), 0))
    ours_cv = time.perf_counter() - start
    layers = np.linspace(1, 32, args.reference_layers).astype(int)
    ref_seconds, ours_scores, ref_scores = 0.0, [], []
    pred = (probes.logits(data.hidden, test) > 0).numpy()
    for i in layers:
        log(f"ours with CV: {ours_cv:.1f}s; scikit-learn, layer {i} ...")
        x = ((data.hidden[i].float() - probes.mean[i]) / probes.std[i]).numpy()
        seconds, ref_pred = reference(x, y, train, test)
        ref_seconds += seconds
        ours_scores.append(scores(pred[i], y[test]))
        ref_scores.append(scores(ref_pred, y[test]))
    per_layer, ref_per_layer = ours / 33, ref_seconds / len(layers)
    ours_mean, ref_mean = np.mean(ours_scores, 0), np.mean(ref_scores, 0)
    result = {
        "size": size,
        "c": C,
        "seconds": round(ours, 2),
        "seconds_per_layer": round(per_layer, 3),
        "seconds_with_cv": round(ours_cv, 2),
        "sklearn_seconds_per_layer": round(ref_per_layer, 2),
        "reference_layers": layers.tolist(),
        "speedup": round(ref_per_layer / per_layer, 1),
        "speedup_with_cv": round(ref_per_layer / (ours_cv / 33), 1),
        "accuracy": round(float(ours_mean[0]), 4),
        "sklearn_accuracy": round(float(ref_mean[0]), 4),
        "balanced_accuracy": round(float(ours_mean[1]), 4),
        "sklearn_balanced_accuracy": round(float(ref_mean[1]), 4),
        "max_iterations": int(probes.convergence.iterations.max()),
        "at_cap": int((~probes.convergence.converged).sum()),
    }
    print(json.dumps(result))


if __name__ == "__main__":
    main()
