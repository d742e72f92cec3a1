"""How much test balanced accuracy the C search gives away: the table of docs/probing.md ("Choosing C").

    .venv/bin/python scripts/c_search_check.py runs/s20/activations runs/default/activations ... [--layers 0 4 8]

Per store: the split and label filter of ``vlaprobe train`` with its defaults (seed 0); the C search of the
default probes (both heads together, as ``vlaprobe train``); then the probes fit on the whole training split
at every C of the grid (warm-started from the strongest penalty, the minimisers the search's final fits
reach) and scored on the test episodes. Per head, the test balanced accuracy (mean over the head's atoms) of

- the chosen C per layer (the default search: CV balanced accuracy, the smallest C within the tolerance);
- the ORACLE: per layer the grid's C with the best *test* figure (a reference, never a selection rule);
- the old rule: the grid (0.01, 0.1, 1) and the lowest CV log-loss (from the same folds' losses);
- the lowest CV log-loss on the whole grid,

at the best layer (each rule's own) and averaged over the layers, with how many layers chose an end of the
rule's grid. Prints a markdown table and a final JSON line.
"""

from __future__ import annotations

import argparse
import json
import math
import sys
import time

import numpy as np
import torch

from vlaprobe.configs.train import TrainConfig
from vlaprobe.errors import VlaprobeError
from vlaprobe.probes.apply import apply_probes_to_rows
from vlaprobe.probes.data import load_store
from vlaprobe.probes.evaluate import column_groups
from vlaprobe.probes.lbfgs import fit_logistic, l2_of_c
from vlaprobe.probes.metrics import confusion_by_group, metrics_from_counts
from vlaprobe.probes.split import filter_labels, make_folds, rows_of
from vlaprobe.probes.trainer import fit_probes, training_matrix

OLD_GRID = (0.01, 0.1, 1.0)


def test_scores(
    hidden: torch.Tensor,
    y: np.ndarray,
    train: np.ndarray,
    test: np.ndarray,
    grid: list[float],
    cfg: TrainConfig,
) -> np.ndarray:
    """(grid, layers, atoms) test balanced accuracy of the probes fit on ``train`` at each C."""
    device = torch.device("cpu")
    x, mean, std = training_matrix(hidden, train, device, True)
    assert mean is not None and std is not None
    targets = torch.as_tensor(y[train], dtype=torch.float32)
    threshold_logit = math.log(cfg.probe.threshold / (1 - cfg.probe.threshold))
    out, start = [], None
    for c in grid:
        l2 = torch.full((x.shape[0], y.shape[1]), float(l2_of_c(c, len(train))))
        p = cfg.probe
        w, b, _ = fit_logistic(x, targets, l2, tol=p.tol, max_iter=p.max_iter, history=p.history, init=start)
        start = (w, b)
        z = apply_probes_to_rows(hidden, w, b, mean, std, test)
        counts = confusion_by_group(z > threshold_logit, y[test], np.zeros(len(test)), 1)[0]
        out.append(metrics_from_counts(counts)["balanced_accuracy"])
    return np.stack(out)


def _pick(per_layer: np.ndarray, chosen: np.ndarray, grid: list[float]) -> np.ndarray:
    """(layers,) the figure at each layer's chosen C from (grid, layers)."""
    at = np.searchsorted(grid, chosen)
    return per_layer[at, np.arange(per_layer.shape[1])]


def _row(values: np.ndarray) -> dict[str, float]:
    return {"best": round(float(np.nanmax(values)), 4), "mean": round(float(np.nanmean(values)), 4)}


def check(store: str, layers: tuple[int, ...] = ()) -> dict[str, dict]:
    """Per head: the figures of each rule (see the module docstring), on ``layers`` (default: all)."""
    cfg = TrainConfig(store=store, layers=layers)
    data = load_store(store, heads=cfg.heads, layers=cfg.layers)
    (fold,) = make_folds(data.episode_tasks, cfg.split, cfg.seed)
    train, test = rows_of(data.episode, fold.train), rows_of(data.episode, fold.test)
    heads, kept = [], {}
    for head in cfg.heads:
        k = filter_labels(
            [data.labels[head][train]], data.atom_names[head], cfg.min_frequency, cfg.max_frequency
        )
        if len(k.kept):
            heads.append(head)
            kept[head] = k.kept
    y = np.concatenate([data.labels[h][:, kept[h]] for h in heads], 1)
    column_head = np.concatenate([np.full(len(kept[h]), i) for i, h in enumerate(heads)])
    started = time.perf_counter()
    probes = fit_probes(
        data.hidden, y, train, cfg.probe, seed=cfg.seed + 1, groups=column_groups(data, column_head, 0)
    )
    search_seconds = time.perf_counter() - started
    cv = probes.cv  # None where no fold can be held out: every layer then takes --probe.c-without-cv
    assert probes.c is not None
    grid = sorted(float(c) for c in cfg.probe.c_grid)
    scores = test_scores(data.hidden, y, train, test, grid, cfg)  # (grid, layers, atoms)
    old = [grid.index(c) for c in OLD_GRID]
    out: dict[str, dict] = {}
    for i, head in enumerate(heads):
        cols = column_head == i
        with np.errstate(invalid="ignore"):
            per_layer = np.nanmean(scores[:, :, cols], 2)  # (grid, layers)
        chosen = probes.c[:, np.flatnonzero(cols)[0]]
        rules = {"chosen": _pick(per_layer, chosen, grid), "oracle": np.nanmax(per_layer, 0)}
        old_chosen = np.full(len(chosen), np.nan)
        if cv is not None:  # the log-loss rules, from the same folds' losses
            loss = cv.of_group(i)[0]
            old_chosen = np.asarray(OLD_GRID)[np.argmin(loss[:, old], 1)]
            rules["old_grid_log_loss"] = _pick(per_layer, old_chosen, grid)
            rules["wide_grid_log_loss"] = _pick(per_layer, np.asarray(grid)[np.argmin(loss, 1)], grid)
        figures = {name: _row(v) for name, v in rules.items()}
        out[head] = {
            "atoms": int(cols.sum()),
            **figures,
            "gap_best": round(figures["oracle"]["best"] - figures["chosen"]["best"], 4),
            "gap_mean": round(figures["oracle"]["mean"] - figures["chosen"]["mean"], 4),
            "searched": cv is not None,
            "chosen_at_edge": 0 if cv is None else int(cv.edge_of(i).sum()),
            "old_at_edge": int(np.isin(old_chosen, (OLD_GRID[0], OLD_GRID[-1])).sum()),
            "layers": len(chosen),
            "chosen_c": {f"{c:g}": int((chosen == c).sum()) for c in grid if (chosen == c).any()},
        }
    return {
        "episodes": len(data.episode_keys),
        "train_episodes": len(fold.train),
        "search_seconds": round(search_seconds, 1),
        "heads": out,
    }


def table(results: dict[str, dict]) -> str:
    """The markdown table of docs/probing.md."""
    lines = [
        "| store (episodes) | head | chosen C: best layer / mean over layers | oracle | gap | old grid, log-loss "
        "| wide grid, log-loss | layers at a grid end: chosen / old |",
        "| --- | --- | --- | --- | --- | --- | --- | --- |",
    ]
    for store, r in results.items():
        for head, h in r["heads"].items():
            cells = [
                f"{h[k]['best']:.3f} / {h[k]['mean']:.3f}" if k in h else "no folds"
                for k in ("chosen", "oracle", "old_grid_log_loss", "wide_grid_log_loss")
            ]
            if not h["searched"]:
                cells[0] += f" (C = {next(iter(h['chosen_c']))}, not searched)"
            lines.append(
                f"| `{store}` ({r['episodes']}) | {head} | {cells[0]} | {cells[1]} | "
                f"{h['gap_best']:.3f} / {h['gap_mean']:.3f} | {cells[2]} | {cells[3]} | "
                f"{h['chosen_at_edge']} / {h['old_at_edge']} of {h['layers']} |"
            )
    return "\n".join(lines)


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("stores", nargs="+", help="activation stores (vlaprobe collect --out)")
    parser.add_argument(
        "--layers", type=int, nargs="+", default=[], help="hidden states to check (default: all)"
    )
    args = parser.parse_args()
    torch.set_num_threads(1)
    results = {}
    try:
        for store in args.stores:
            results[store] = check(store, tuple(args.layers))
            print(json.dumps({store: results[store]}), file=sys.stderr, flush=True)
    except VlaprobeError as err:
        print(f"error: {err}", file=sys.stderr)
        return 2
    print(table(results))
    print(json.dumps(results))
    return 0


if __name__ == "__main__":
    sys.exit(main())
