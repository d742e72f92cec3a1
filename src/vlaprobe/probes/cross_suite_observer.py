"""The observer control of ``vlaprobe cross-suite``: the probes trained on the control observer's (the untrained
network's) store of the source suite, scored on the target store that network observed. The two target stores
must hold the same episodes, so the differences probe - control are paired over the same resamples.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from vlaprobe.configs.cross_suite import CrossSuiteConfig
from vlaprobe.errors import VlaprobeError
from vlaprobe.probes.cross_suite_inputs import (
    UNDEFINED,
    Curve,
    Labels,
    at_layer,
    check_pair,
    difference,
    est,
    read_labels,
    saved_logits,
    target_of,
    threshold_logit,
)
from vlaprobe.probes.cross_suite_result import ControlInfo, HeadTransfer, ObserverTransfer
from vlaprobe.probes.probeset import ProbeSet


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
