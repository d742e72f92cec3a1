"""Our probes against scikit-learn's LogisticRegression on a real store: the parity figure of docs/probing.md.

    .venv/bin/python scripts/sklearn_parity.py runs/default/activations [--layers 0 8 16 24 32]

Splits and filters the store exactly as ``vlaprobe train`` does with its defaults (seed 0), fits our probes
with the default settings (standardised, C per layer and head by cross-validation, L-BFGS to 1e-4), then
per layer and atom a scikit-learn ``LogisticRegression`` with the same C on the same standardised features,
solved tightly (tol 1e-6) as the converged reference. Prints, per head, the largest and the mean absolute
difference of the mean balanced accuracy over the layers, and a final JSON line.
"""

from __future__ import annotations

import argparse
import json
import sys
import time

import numpy as np
import torch

from vlaprobe.configs.train import TrainConfig
from vlaprobe.errors import VlaprobeError
from vlaprobe.probes.data import load_store
from vlaprobe.probes.evaluate import column_groups
from vlaprobe.probes.metrics import metrics_from_counts
from vlaprobe.probes.split import filter_labels, make_folds, rows_of
from vlaprobe.probes.trainer import fit_probes


def balanced(pred: np.ndarray, truth: np.ndarray) -> float:
    """Mean balanced accuracy over the atoms (columns) defined on these rows."""
    counts = np.stack([(pred & truth), (pred & ~truth), (~pred & truth), (~pred & ~truth)], -1).sum(0)
    return float(np.nanmean(metrics_from_counts(counts.astype(float))["balanced_accuracy"]))


def parity(store: str, layers: tuple[int, ...]) -> dict[str, dict[str, float | int]]:
    """Per head: layers compared, largest and mean |ours - scikit-learn| of the mean balanced accuracy."""
    from sklearn.linear_model import LogisticRegression

    cfg = TrainConfig(store=store, layers=layers)
    data = load_store(store, heads=cfg.heads, layers=cfg.layers)
    (fold,) = make_folds(data.episode_tasks, cfg.split, cfg.seed)
    train, test = rows_of(data.episode, fold.train), rows_of(data.episode, fold.test)
    out: dict[str, dict[str, float | int]] = {}
    for head in cfg.heads:
        kept = filter_labels([data.labels[head][train]], data.atom_names[head], 0.01, 0.99).kept
        if not len(kept):
            continue
        y = data.labels[head][:, kept]
        groups = column_groups(data, np.zeros(len(kept), np.int64), 0)
        probes = fit_probes(data.hidden, y, train, cfg.probe, seed=cfg.seed + 1, groups=groups)
        assert probes.mean is not None and probes.std is not None and probes.c is not None
        ours = (probes.logits(data.hidden, test) > 0).numpy()
        diffs = []
        for i in range(len(data.layers)):
            x = ((data.hidden[i].float() - probes.mean[i]) / probes.std[i]).numpy()
            ref = np.zeros((len(test), len(kept)), bool)
            for j in range(len(kept)):
                model = LogisticRegression(C=float(probes.c[i, j]), tol=1e-6, max_iter=5000)
                ref[:, j] = model.fit(x[train], y[train, j]).predict(x[test]).astype(bool)
            diffs.append(abs(balanced(ours[i], y[test]) - balanced(ref, y[test])))
            print(f"{head} layer {data.layers[i]}: |difference| {diffs[-1]:.4f}", file=sys.stderr, flush=True)
        out[head] = {
            "layers": len(diffs),
            "atoms": len(kept),
            "max_abs_diff": round(max(diffs), 4),
            "mean_abs_diff": round(float(np.mean(diffs)), 4),
        }
    return out


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("store", help="activation store (vlaprobe collect --out)")
    parser.add_argument(
        "--layers", type=int, nargs="*", default=[], help="hidden-state indices (default: all)"
    )
    args = parser.parse_args()
    torch.set_num_threads(1)
    start = time.perf_counter()
    try:
        result = parity(args.store, tuple(args.layers))
    except VlaprobeError as err:
        print(f"error: {err}", file=sys.stderr)
        return 2
    print(
        json.dumps({"store": args.store, "heads": result, "seconds": round(time.perf_counter() - start, 1)})
    )
    return 0


if __name__ == "__main__":
    sys.exit(main())
