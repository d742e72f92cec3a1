"""The metadata of saved probes (``probes.json``) as dataclasses: one writer, one reader.

``vlaprobe train`` builds a :class:`ProbesMeta` (:func:`vlaprobe.probes.record.probe_meta`) and
:meth:`vlaprobe.probes.probeset.ProbeSet.save` writes it with :func:`write_probes_meta`; every reader (the
probe set, ``vlaprobe hypotheses``, the report, the live server) goes through :func:`read_probes_meta`.

Format version 2 (version 1 lacked them): each head's ``tied_layers`` (the layers statistically tied with the
best, the best included) and ``default_layer``, the earliest of them: the layer the live server, ``vlaprobe
monitor`` and :class:`~vlaprobe.probes.probeset.ProbeSet` read a head at when no layer is given. A version-1
file is read with ``tied_layers = [best_layer]`` and ``default_layer = best_layer``.
"""

from __future__ import annotations

import json
from dataclasses import asdict, dataclass, field
from pathlib import Path

from vlaprobe.errors import VlaprobeError
from vlaprobe.files import JsonObject, from_json, read_versioned, write_atomic
from vlaprobe.probes.results import DroppedAtom

FORMAT = "vlaprobe-probes"
FORMAT_VERSION = 2
READS = (1, 2)
"""Format versions :func:`read_probes_meta` reads (1: without ``tied_layers`` / ``default_layer``)."""
META_FILE = "probes.json"


@dataclass
class HeadMeta:
    """One head's probes: which atoms they predict and which layer reads them."""

    kept: list[str]
    """Probed atoms: the weight columns, in order."""
    best_layer: int
    """Hidden-state index of the best layer on the held-out data (by ``best_metric``)."""
    best_metric: str = ""
    atom_names: list[str] = field(default_factory=list)
    """Every atom of the head in vocabulary order, probed or not (empty: the kept ones)."""
    kept_index: list[int] = field(default_factory=list)
    """Positions of the kept atoms among ``atom_names``."""
    dropped: list[DroppedAtom] = field(default_factory=list)
    """Atoms left unprobed (too rare or too common in training)."""
    best_value: float | None = None
    best_rule: str = ""
    tied_layers: list[int] = field(default_factory=list)
    """Layers statistically tied with the best (the best included); empty in a version-1 file: the best only."""
    default_layer: int | None = None
    """``min(tied_layers)``: the layer read when none is given (None in a version-1 file: the best)."""

    def __post_init__(self) -> None:
        if not self.tied_layers:
            self.tied_layers = [self.best_layer]
        if self.default_layer is None:
            self.default_layer = min(self.tied_layers)


@dataclass
class TrainedOn:
    episodes: int = 0
    steps: int = 0
    split: str = "training split"
    """"training split", or "all episodes (refit after k-fold)"."""


@dataclass
class ProbesMeta:
    """The content of ``probes.json``."""

    model_id: str
    pooling: str
    hidden_size: int
    num_hidden_states: int
    layers: list[int]
    """Hidden-state index of each weight slice."""
    threshold: float
    heads: dict[str, HeadMeta]
    standardized: bool = True
    action_tokens: str | None = None
    trained_on: TrainedOn = field(default_factory=TrainedOn)
    config: JsonObject = field(default_factory=dict)
    """The training configuration (``vlaprobe.configs.train.TrainConfig`` as JSON)."""
    seeds: dict[str, int] = field(default_factory=dict)
    versions: dict[str, str | None] = field(default_factory=dict)
    created: str = ""
    suite: str = "libero_spatial"
    """The LIBERO suite of the episodes the probes were trained on (files without it: LIBERO-spatial's)."""
    format: str = FORMAT
    format_version: int = FORMAT_VERSION

    @property
    def store(self) -> Path | None:
        """The activation store the probes were trained on (None: not recorded)."""
        store = self.config.get("store")
        return None if store is None else Path(str(store))


def write_probes_meta(folder: str | Path, meta: ProbesMeta) -> Path:
    """Write ``<folder>/probes.json`` atomically (always the current version); return its path."""
    path = Path(folder) / META_FILE
    data = {**asdict(meta), "format": FORMAT, "format_version": FORMAT_VERSION}
    write_atomic(path, json.dumps(data, indent=1, allow_nan=False) + "\n")
    return path


def read_probes_meta(folder: str | Path) -> ProbesMeta:
    """Read ``<folder>/probes.json``; a one-line error if it is missing, damaged or of an unknown version."""
    path = Path(folder) / META_FILE
    if not path.is_file():
        raise VlaprobeError(f"no {META_FILE} in {folder}; pass the folder written by vlaprobe train")
    hint = "retrain the probes with this version of vlaprobe (vlaprobe train)"
    data, _ = read_versioned(path, FORMAT, "probe file", READS, hint)
    return from_json(ProbesMeta, data, path, hint)
