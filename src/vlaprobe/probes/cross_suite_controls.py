"""The controls of ``vlaprobe cross-suite``: what the source probes must beat on the target store.

- **Shuffled labels**: per head, probes fit on the source store's rows with the labels permuted across steps,
  exactly as ``vlaprobe train``'s shuffled-label control permutes them
  (:func:`~vlaprobe.probes.evaluate.shuffled_labels`: the saved probes' training rows, re-derived with
  ``vlaprobe train``'s split, its ``shuffle`` seed, one permutation after another), by the one trainer
  (:func:`~vlaprobe.probes.trainer.fit_probes`) with the C the saved probes were fit with at that layer
  (``evaluation.json``'s ``fit.c``), at the probes' own best layer and the target's best layer; applied to the
  target rows and scored by the same scorer on the same resamples. Figure: the mean over the permutations, and
  the paired difference probe - shuffled.
- **Control observer**: the probes trained on the control observer's (the untrained network's) store of the
  source suite, scored on the target store that network observed. The two target stores must hold the same
  episodes, so the difference probe - control is paired over the same resamples.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from vlaprobe.configs.cross_suite import CrossSuiteConfig
from vlaprobe.errors import VlaprobeError
from vlaprobe.probes.bootstrap import Estimate, nan_mean, nan_std
from vlaprobe.probes.cross_suite_inputs import (
    Curve,
    Labels,
    check_pair,
    est,
    num,
    read_labels,
    saved_logits,
    target_of,
    threshold_logit,
)
from vlaprobe.probes.cross_suite_result import (
    ControlInfo,
    HeadTransfer,
    ObserverTransfer,
    ShuffledAt,
    ShuffledInfo,
)
from vlaprobe.probes.probeset import ProbeSet

if TYPE_CHECKING:
    import torch

    from vlaprobe.configs.train import ProbeConfig
    from vlaprobe.probes.data import ProbeData

UNDEFINED = Estimate(None, None, None)


def at_layer(curve: tuple[np.ndarray, np.ndarray], layers: list[int], layer: int) -> tuple[float, np.ndarray]:
    """A layer curve's value and resamples at ``layer`` (NaN where the curve lacks it)."""
    value, res = curve
    if layer not in layers:
        return float("nan"), np.full(res.shape[0], np.nan)
    i = layers.index(layer)
    return float(value[i]), res[:, i]


def difference(a: tuple[float, np.ndarray], b: tuple[float, np.ndarray]) -> Estimate:
    """``a - b`` paired over the same resamples (undefined where either is)."""
    if not (np.isfinite(a[0]) and np.isfinite(b[0])):
        return UNDEFINED
    return est(a[0] - b[0], a[1] - b[1])


# -- shuffled labels --------------------------------------------------------------------------------------


def _saved_config(probes: ProbeSet) -> tuple[ProbeConfig, Path]:
    from vlaprobe.configs.train import ProbeConfig
    from vlaprobe.files import from_json

    where = Path(probes.where) / "probes.json"
    hint = "retrain the probes with vlaprobe train, or pass --no-shuffled-control"
    cfg = from_json(ProbeConfig, dict(probes.meta.config.get("probe") or {}), where, hint)
    return replace(cfg, device="auto"), where


def source_rows(probes: ProbeSet, data: ProbeData) -> tuple[np.ndarray, str]:
    """The source rows the saved probes were fit on, as ``vlaprobe train`` chose them, and how they were chosen."""
    from vlaprobe.configs.train import SplitConfig
    from vlaprobe.files import from_json
    from vlaprobe.probes.results import read_evaluation
    from vlaprobe.probes.split import make_folds, rows_of

    if probes.refit_on_all:
        return np.arange(data.num_steps), "every row of the source store (the saved probes were refit on all)"
    where = Path(probes.where) / "probes.json"
    hint = "retrain the probes with vlaprobe train, or pass --no-shuffled-control"
    split = from_json(SplitConfig, dict(probes.meta.config.get("split") or {}), where, hint)
    folds = make_folds(data.episode_tasks, split, int(probes.meta.seeds.get("split", 0)))
    if len(folds) != 1:
        raise VlaprobeError(f"{where} says the probes were fit on one training split, but its split has "
                            f"{len(folds)} folds; {hint}")  # fmt: skip
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


def shuffled_control(
    cfg: CrossSuiteConfig, probes: ProbeSet, src: Path, scored: dict[str, tuple[HeadTransfer, Curve]],
    target_hidden: torch.Tensor, target: Labels, weights: np.ndarray,
) -> tuple[ShuffledInfo, dict[str, list[ShuffledAt]]]:  # fmt: skip
    """Fit, score and compare the shuffled-label control of every scored head (see the module docstring)."""
    from vlaprobe.probes.data import load_store
    from vlaprobe.probes.evaluate import shuffled_labels
    from vlaprobe.probes.trainer import fit_probes

    layers = next(iter(scored.values()))[0].layers  # the target's layers (every head has the same)
    wanted = {h: list(dict.fromkeys(x for x in (t.source_layer, t.best_layer) if x in layers))
              for h, (t, _) in scored.items()}  # fmt: skip
    fit_layers = sorted({x for w in wanted.values() for x in w})
    probe_cfg, _ = _saved_config(probes)
    split = probes.meta.config.get("split") or {}
    data = load_store(
        src, heads=list(scored), layers=fit_layers, success_only=bool(split.get("success_only"))
    )
    rows, rows_how = source_rows(probes, data)
    cols = {h: np.array([data.atom_names[h].index(a) for a in t.atoms]) for h, (t, _) in scored.items()}
    targets = np.concatenate([data.labels[h][:, c] for h, c in cols.items()], axis=1)
    defined = data.targets_defined(cols)
    seed = int(probes.meta.seeds.get("shuffle", 0))
    rng = np.random.default_rng(seed)
    blocks = [shuffled_labels(targets, rows, rng, defined) for _ in range(cfg.shuffled_permutations)]
    c_head = {h: probe_c(probes, h, fit_layers) for h in scored}
    c = np.concatenate([np.repeat(c_head[h][0][:, None], len(cols[h]), 1) for h in scored], axis=1)
    fitted = fit_probes(
        data.hidden, np.concatenate([b for b, _ in blocks], axis=1), rows, probe_cfg,
        int(probes.meta.seeds.get("probe", 0)), c=np.tile(c, cfg.shuffled_permutations),
        defined=None if defined is None else np.concatenate([m for _, m in blocks if m is not None], axis=1),
    )  # fmt: skip
    logits = fitted.logits(target_hidden[[layers.index(x) for x in fit_layers]])
    k, start, out = targets.shape[1], 0, {}
    for h, (_, curve) in scored.items():
        n = len(cols[h])
        scorer = target_of(target, h, weights)
        runs = [scorer.score(logits[:, :, p * k + start : p * k + start + n] > threshold_logit(probes))
                for p in range(cfg.shuffled_permutations)]  # fmt: skip
        start += n
        mean = Curve(np.mean([r.point for r in runs], 0), np.mean([r.resampled for r in runs], 0)).layer()
        per_perm = np.stack([nan_mean(r.point, 1) for r in runs])
        spread = nan_std(per_perm, 0) if len(runs) > 1 else np.full(len(fit_layers), np.nan)
        probe_curve = curve.layer()
        out[h] = [
            ShuffledAt(
                layer=x,
                c=float(c_head[h][0][fit_layers.index(x)]),
                balanced_accuracy=est(*at_layer(mean, fit_layers, x)),
                spread=num(spread[fit_layers.index(x)]),
                probe_minus_shuffled=difference(
                    at_layer(probe_curve, layers, x), at_layer(mean, fit_layers, x)
                ),
            )
            for x in wanted[h]
        ]
    c_how = next(iter(c_head.values()))[1]
    return ShuffledInfo(cfg.shuffled_permutations, seed, rows_how, c_how), out


# -- the control observer ----------------------------------------------------------------------------------


@dataclass(frozen=True)
class Control:
    probes: ProbeSet
    shared: dict[str, list[str]]


def check_control(cfg: CrossSuiteConfig, probes: ProbeSet) -> Control:
    """Refuse a control pair that cannot be compared with the probes (one line each)."""
    from vlaprobe.collection.store import ActivationStore, read_store_meta

    if cfg.control_probes is None or cfg.control_store is None:
        raise VlaprobeError("--control-probes and --control-store go together; pass both (or neither)")
    control = ProbeSet.load(cfg.control_probes)
    if control.suite != probes.suite:
        raise VlaprobeError(
            f"--control-probes {cfg.control_probes} were trained on {control.suite}, the probes in {cfg.probes} on "
            f"{probes.suite}; pass the control observer's probes of the same source store"
        )
    if control.model_id == probes.model_id:
        raise VlaprobeError(
            f"--control-probes {cfg.control_probes} read the same model ({probes.model_id!r}) as the probes: the "
            "control would compare the probes with themselves; pass the probes trained on the control observer's "
            "store (control-probes of vlaprobe run)"
        )
    target, other = read_store_meta(cfg.store), read_store_meta(cfg.control_store)
    if other.suite != target.suite:
        raise VlaprobeError(
            f"--control-store {cfg.control_store} is a {other.suite} store, --store {cfg.store} a {target.suite} "
            "one; pass the store the control observer saw of the same episodes"
        )
    shared = check_pair(replace(cfg, probes=cfg.control_probes, store=cfg.control_store), control)
    keys = [[e.key for e in ActivationStore.open(p).episodes(success_only=cfg.success_only)]
            for p in (cfg.store, cfg.control_store)]  # fmt: skip
    if keys[0] != keys[1]:
        raise VlaprobeError(
            f"--control-store {cfg.control_store} holds other episodes ({len(keys[1])}) than --store {cfg.store} "
            f"({len(keys[0])}): the comparison is paired over the same episodes; pass the control observer's "
            "store of those episodes (control/activations of the same vlaprobe run)"
        )
    return Control(control, shared)


def observer_control(
    cfg: CrossSuiteConfig, control: Control, scored: dict[str, tuple[HeadTransfer, Curve]], target: Labels,
    weights: np.ndarray,
) -> tuple[ControlInfo, dict[str, ObserverTransfer]]:  # fmt: skip
    """The control observer's probes on its target store, and the paired differences from the probes."""
    from vlaprobe.collection.store import read_store_meta
    from vlaprobe.probes.data import load_store
    from vlaprobe.probes.ties import tie_set

    assert cfg.control_store is not None
    atoms = {h: [a for a in t.atoms if a in control.shared.get(h, [])] for h, (t, _) in scored.items()}
    atoms = {h: a for h, a in atoms.items() if a}
    probes = control.probes
    info = ControlInfo(str(cfg.control_probes), str(cfg.control_store), probes.model_id)
    if not atoms:
        return info, {}
    labels = read_labels(cfg.control_store, atoms, cfg.assets, cfg.success_only)
    if labels.keys != target.keys:
        raise VlaprobeError(
            f"--control-store {cfg.control_store} holds other episodes than --store {cfg.store}"
        )
    depth = read_store_meta(cfg.control_store).num_hidden_states
    layers = [x for x in probes.layers if x < depth]
    data = load_store(cfg.control_store, heads=list(atoms), layers=layers, success_only=cfg.success_only)
    out = {}
    for h, names in atoms.items():
        transfer, curve = scored[h]
        c = target_of(labels, h, weights).score(
            saved_logits(probes, data.hidden, layers, h, names) > threshold_logit(probes)
        )
        value, res = c.layer()
        if np.all(np.isnan(value)):
            continue
        best = int(np.nanargmax(value))
        mine = curve.columns([transfer.atoms.index(a) for a in names]).layer()
        own = probes.best_layer(h)
        out[h] = ObserverTransfer(
            atoms=names, scored=int((~np.isnan(c.point[0])).sum()), layers=layers,
            balanced_accuracy=[est(value[i], res[:, i]) for i in range(len(layers))],
            best_layer=layers[best], tied=[layers[i] for i in tie_set(value, res, best)], source_layer=own,
            at_source_layer=est(*at_layer((value, res), layers, own)) if own in layers else UNDEFINED,
            probe_minus_observer=difference(
                at_layer(mine, transfer.layers, transfer.source_layer), at_layer((value, res), layers, own)
            ),
            best_minus_best=difference(
                at_layer(mine, transfer.layers, transfer.best_layer), at_layer((value, res), layers, layers[best])
            ),
        )  # fmt: skip
    return info, out
