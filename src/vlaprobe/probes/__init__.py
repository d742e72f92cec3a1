"""Per-layer linear probes: data, split, training, evaluation, and the saved probe set.

Typical use (``docs/probing.md`` has the method)::

    out = train_probes(TrainConfig(store=Path("runs/x/activations")))
    probes = ProbeSet.load(out, model_id=..., pooling=...)
    probes.predict(hidden_states)  # {atom: 0/1} at each head's default layer (earliest tied with the best)

The names below are imported on first use, so that ``vlaprobe.probes.results`` (the evaluation's
dataclasses, read by the report) loads without torch.
"""

from __future__ import annotations

import importlib
from typing import Any

_EXPORTS = {
    "ProbeData": "vlaprobe.probes.data",
    "load_store": "vlaprobe.probes.data",
    "synthetic_data": "vlaprobe.probes.data",
    "ProbeSet": "vlaprobe.probes.probeset",
    "train_on_data": "vlaprobe.probes.train",
    "train_probes": "vlaprobe.probes.train",
}

__all__ = sorted(_EXPORTS)


def __getattr__(name: str) -> Any:
    if name not in _EXPORTS:
        raise AttributeError(f"module 'vlaprobe.probes' has no attribute {name!r}")
    return getattr(importlib.import_module(_EXPORTS[name]), name)
