"""The shuffled-label control of ``vlaprobe cross-suite``: what the source probes must beat on the target store.

Per head, probes fit on the source store's rows with the labels permuted across steps, exactly as ``vlaprobe
train``'s shuffled-label control permutes them (:func:`~vlaprobe.probes.evaluate.shuffled_labels`: the saved
probes' training rows, re-derived with ``vlaprobe train``'s split, its ``shuffle`` seed, one permutation after
another), by the one trainer (:func:`~vlaprobe.probes.trainer.fit_probes`) with the C the saved probes were fit
with at that layer (``evaluation.json``'s ``fit.c``), at the probes' own best layer and the target's best layer;
applied to the target rows and scored by the same scorer on the same resamples. Figure: the mean over the
permutations, and the paired difference probe - shuffled.

The control observer's comparison is :mod:`vlaprobe.probes.cross_suite_observer`.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from vlaprobe.configs.cross_suite import CrossSuiteConfig
from vlaprobe.errors import VlaprobeError
from vlaprobe.probes.bootstrap import nan_mean, nan_std
from vlaprobe.probes.cross_suite_inputs import (
    Curve,
    Labels,
    at_layer,
    difference,
    est,
    num,
    target_of,
    threshold_logit,
)
from vlaprobe.probes.cross_suite_result import (
    HeadTransfer,
    ShuffledAt,
    ShuffledInfo,
)
from vlaprobe.probes.probeset import ProbeSet

if TYPE_CHECKING:
    import torch

    from vlaprobe.configs.train import ProbeConfig
    from vlaprobe.probes.data import ProbeData
    from vlaprobe.probes.trainer import LinearProbes


HINT = "retrain the probes with vlaprobe train, or pass --no-shuffled-control"


def _saved_config(probes: ProbeSet) -> ProbeConfig:
    """The probe configuration the saved probes were trained with (on this machine's device)."""
    from vlaprobe.configs.train import ProbeConfig
    from vlaprobe.files import from_json

    where = Path(probes.where) / "probes.json"
    cfg = from_json(ProbeConfig, dict(probes.meta.config.get("probe") or {}), where, HINT)
    return replace(cfg, device="auto")


def source_rows(probes: ProbeSet, data: ProbeData) -> tuple[np.ndarray, str]:
    """The source rows the saved probes were fit on, as ``vlaprobe train`` chose them, and how they were chosen."""
    from vlaprobe.configs.train import SplitConfig
    from vlaprobe.files import from_json
    from vlaprobe.probes.results import read_evaluation
    from vlaprobe.probes.split import make_folds, rows_of

    if probes.refit_on_all:
        return np.arange(data.num_steps), "every row of the source store (the saved probes were refit on all)"
    where = Path(probes.where) / "probes.json"
    split = from_json(SplitConfig, dict(probes.meta.config.get("split") or {}), where, HINT)
    folds = make_folds(data.episode_tasks, split, int(probes.meta.seeds.get("split", 0)))
    if len(folds) != 1:
        raise VlaprobeError(f"{where} says the probes were fit on one training split, but its split has "
                            f"{len(folds)} folds; {HINT}")  # fmt: skip
    test = sorted(data.episode_keys[i] for i in folds[0].test)
    if (Path(probes.where) / "evaluation.json").is_file():
        held = sorted(read_evaluation(probes.where).split.test_episodes)
        if held and held != test:
            raise VlaprobeError(
                f"the source store's episodes give another test split ({len(test)} episodes) than the one the "
                f"probes in {probes.where} held out ({len(held)}): it is not the store they were trained on; pass "
                "that one as --source-store (or --no-shuffled-control)"
            )
    rows = rows_of(data.episode, folds[0].train)
    return rows, f"the saved probes' training split ({len(folds[0].train)} episodes, {len(rows)} rows)"


def probe_c(probes: ProbeSet, head: str, layers: list[int]) -> tuple[np.ndarray, str]:
    """The C the saved probes of ``head`` were fit with at ``layers``, and where it was read."""
    from vlaprobe.probes.results import read_evaluation

    grid = list((probes.meta.config.get("probe") or {}).get("c_grid") or [])
    fit = None
    if (Path(probes.where) / "evaluation.json").is_file():
        ev = read_evaluation(probes.where)
        fit = ev.heads[head].fit if head in ev.heads else None
    if fit is not None and isinstance(fit.c, list) and len(fit.c) == len(probes.layers):
        c = np.array([float(fit.c[probes.layers.index(layer)]) for layer in layers])
        how = "evaluation.json's fit.c: the C each layer's probes were fit with"
        if probes.refit_on_all and len(grid) > 1:
            how += " (of the last fold: the refit on all episodes searched C again and did not record it)"
        return c, how
    if len(grid) == 1:
        return np.full(len(layers), float(grid[0])), "the one C of the probes' c_grid"
    raise VlaprobeError(
        f"{probes.where} records no C for the {head} probes (no evaluation.json with fit.c): the shuffled control "
        "is fit with the probes' C; pass the folder vlaprobe train wrote, or --no-shuffled-control"
    )


@dataclass(frozen=True)
class ShuffledProbes:
    """Probes fit on permuted source labels: per permutation a block of columns, the heads' atoms in turn."""

    probes: LinearProbes
    layers: list[int]
    """Hidden-state index of each of their layers."""
    columns: dict[str, slice]
    """Head -> its atoms' columns within one block."""
    permutations: int
    c: dict[str, np.ndarray]
    """Head -> (layers,) the C they were fit with."""
    info: ShuffledInfo

    def logits(self, hidden: torch.Tensor, head: str) -> list[torch.Tensor]:
        """Per permutation, the logits (layers, rows, atoms) of ``head`` on ``hidden`` ((layers, rows, hidden) at
        :attr:`layers`)."""
        out = self.probes.logits(hidden)
        width = out.shape[2] // self.permutations
        cols = self.columns[head]
        return [out[:, :, p * width + cols.start : p * width + cols.stop] for p in range(self.permutations)]


def fit_shuffled(
    probes: ProbeSet, src: Path, atoms: dict[str, list[str]], layers: list[int], permutations: int
) -> ShuffledProbes:
    """The shuffled-label control of ``atoms`` (head -> atoms the probes probe) at ``layers``, fit on the source
    store ``src`` as ``vlaprobe train`` fit its own (see the module docstring)."""
    from vlaprobe.probes.data import load_store
    from vlaprobe.probes.evaluate import shuffled_labels
    from vlaprobe.probes.trainer import fit_probes

    probe_cfg = _saved_config(probes)
    split = probes.meta.config.get("split") or {}
    success_only = bool(split.get("success_only"))
    data = load_store(src, heads=list(atoms), layers=layers, success_only=success_only)
    rows, rows_how = source_rows(probes, data)
    cols = {h: np.array([data.atom_names[h].index(a) for a in names]) for h, names in atoms.items()}
    targets = np.concatenate([data.labels[h][:, c] for h, c in cols.items()], axis=1)
    defined = data.targets_defined(cols)
    seed = int(probes.meta.seeds.get("shuffle", 0))
    rng = np.random.default_rng(seed)
    blocks = [shuffled_labels(targets, rows, rng, defined) for _ in range(permutations)]
    c_head = {h: probe_c(probes, h, layers) for h in atoms}
    c = np.concatenate([np.repeat(c_head[h][0][:, None], len(cols[h]), 1) for h in atoms], axis=1)
    fitted = fit_probes(
        data.hidden, np.concatenate([b for b, _ in blocks], axis=1), rows, probe_cfg,
        int(probes.meta.seeds.get("probe", 0)), c=np.tile(c, permutations),
        defined=None if defined is None else np.concatenate([m for _, m in blocks if m is not None], axis=1),
    )  # fmt: skip
    starts = np.cumsum([0, *(len(c) for c in cols.values())])
    return ShuffledProbes(
        probes=fitted,
        layers=list(layers),
        columns={h: slice(int(starts[i]), int(starts[i + 1])) for i, h in enumerate(atoms)},
        permutations=permutations,
        c={h: v[0] for h, v in c_head.items()},
        info=ShuffledInfo(permutations, seed, rows_how, next(iter(c_head.values()))[1]),
    )


def shuffled_control(
    cfg: CrossSuiteConfig, probes: ProbeSet, src: Path, scored: dict[str, tuple[HeadTransfer, Curve]],
    target_hidden: torch.Tensor, target: Labels, weights: np.ndarray,
) -> tuple[ShuffledInfo, dict[str, list[ShuffledAt]]]:  # fmt: skip
    """Fit, score and compare the shuffled-label control of every scored head at its source and best layers."""
    layers = next(iter(scored.values()))[0].layers  # the target's layers (every head has the same)
    wanted = {h: list(dict.fromkeys(x for x in (t.source_layer, t.best_layer) if x in layers))
              for h, (t, _) in scored.items()}  # fmt: skip
    fit_layers = sorted({x for w in wanted.values() for x in w})
    atoms = {h: t.atoms for h, (t, _) in scored.items()}
    shuffled = fit_shuffled(probes, src, atoms, fit_layers, cfg.shuffled_permutations)
    hidden = target_hidden[[layers.index(x) for x in fit_layers]]
    out = {}
    for h, (_, curve) in scored.items():
        scorer = target_of(target, h, weights)
        runs = [scorer.score(x > threshold_logit(probes)) for x in shuffled.logits(hidden, h)]
        mean = Curve(np.mean([r.point for r in runs], 0), np.mean([r.resampled for r in runs], 0)).layer()
        per_perm = np.stack([nan_mean(r.point, 1) for r in runs])
        spread = nan_std(per_perm, 0) if len(runs) > 1 else np.full(len(fit_layers), np.nan)
        probe_curve = curve.layer()
        out[h] = [
            ShuffledAt(
                layer=x,
                c=float(shuffled.c[h][fit_layers.index(x)]),
                balanced_accuracy=est(*at_layer(mean, fit_layers, x)),
                spread=num(spread[fit_layers.index(x)]),
                probe_minus_shuffled=difference(
                    at_layer(probe_curve, layers, x), at_layer(mean, fit_layers, x)
                ),
            )
            for x in wanted[h]
        ]
    return shuffled.info, out
