"""The evaluation of a probe run (``evaluation.json``) as dataclasses, shared by its writer and its readers.

``vlaprobe train`` builds an :class:`Evaluation` and writes it with :func:`write_evaluation`; ``vlaprobe
report`` (and anything else) reads it with :func:`read_evaluation`. This module imports no torch. Arrays are
nested lists with ``None`` for undefined (NaN) values; :func:`arr` turns them back into float arrays.

Format version 2 (version 1 had none of these): every figure records in how many bootstrap resamples it was
defined (``defined``); the shuffled-label control is the mean of several permutations, with their spread
(``control_spread``); the split records the realized test fraction next to the requested one. Version 3:
the task and task x time baselines (``task_baseline``, ``task_time_baseline``) and the selectivity over the
latter (``selectivity_task_time``); how each probe was fit (``fit``: C per layer, cross-validation losses,
iterations, final loss and gradient norm per probe); averages keep a fixed set of atoms in every resample.
Version 4: the layers tied with the best one (``BestLayer.tied``; a version-3 file reads with the best layer
alone) and conditional probing over the task and task x time baselines (``conditional_task``,
``conditional_task_time``; absent from older files). Version 5: the atom families (``families``), the
matched-steps control (``matched``: a within-cell AUC per atom, family and layer, against the observer
control) and the conditional gain per family (``conditional_families``); absent (empty) in older files.
"""

from __future__ import annotations

import json
import math
from collections.abc import Mapping
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import SupportsFloat

import numpy as np

from vlaprobe.errors import VlaprobeError
from vlaprobe.files import JsonObject, from_json, read_versioned, write_atomic
from vlaprobe.probes.head_results import (
    BestLayer,
    ConditionalProbe,
    DroppedAtom,
    HeadResult,
    Level,
    MatchedPairs,
    MetricSummary,
    Nested,
    ProbeFit,
    Spread,
)

__all__ = [  # with the head records (vlaprobe.probes.head_results), importable from here as before
    "CONFIG_FILE",
    "DECIMALS",
    "EVALUATION_FILE",
    "FORMAT",
    "FORMAT_VERSION",
    "PARTS",
    "READABLE_VERSIONS",
    "BestLayer",
    "Bootstrap",
    "ConditionalProbe",
    "Controls",
    "Dataset",
    "DroppedAtom",
    "Episodes",
    "Evaluation",
    "HeadResult",
    "Level",
    "MatchedPairs",
    "MetricSummary",
    "Nested",
    "ObserverInfo",
    "ProbeFit",
    "SkippedHead",
    "Split",
    "Spread",
    "arr",
    "level",
    "nested",
    "number",
    "read_evaluation",
    "read_test_episodes",
    "write_evaluation",
]

FORMAT = "vlaprobe-evaluation"
FORMAT_VERSION = 5
READABLE_VERSIONS = (3, 4, 5)
"""Format versions :func:`read_evaluation` accepts (older ones gain the new fields' defaults)."""
EVALUATION_FILE = "evaluation.json"
CONFIG_FILE = "config.json"
PARTS = (
    "probe",
    "baseline",
    "time_baseline",
    "task_baseline",
    "task_time_baseline",
    "control",
    "selectivity",
    "selectivity_time",
    "selectivity_task_time",
    "observer",
)
"""The metric summaries a head may have, in display order."""


@dataclass
class SkippedHead:
    reason: str
    dropped: list[DroppedAtom]


@dataclass
class Episodes:
    episodes: int
    steps: int


@dataclass
class Split:
    unit: str
    stratified_by: str
    folds: int
    test_fraction: float
    """The requested share of episodes held out (1/folds for k-fold)."""
    realized_test_fraction: float
    """The share actually held out: test episodes / all episodes (per fold for k-fold), after rounding."""
    train: Episodes
    test: Episodes
    test_episodes: list[str]
    leak_check: str


@dataclass
class Dataset:
    episodes: int
    steps: int
    episodes_per_task: dict[str, int]


@dataclass
class Bootstrap:
    unit: str
    interval: str
    resamples: int
    auprc_resamples: int
    undefined: str
    """How resamples in which a figure is undefined are treated."""


@dataclass
class ObserverInfo:
    model_id: str
    pooling: str
    layers: list[int]
    same_episodes: bool
    steps: int
    episodes: int


@dataclass
class Controls:
    shuffled_labels: bool
    shuffled_permutations: int
    """Label permutations trained for the shuffled-label control (0 without it)."""
    observer: ObserverInfo | None = None


@dataclass
class Evaluation:
    """The content of ``evaluation.json``."""

    model_id: str
    pooling: str
    layers: list[int]
    hidden_size: int
    threshold: float
    metrics: list[str]
    dataset: Dataset
    split: Split
    bootstrap: Bootstrap
    controls: Controls
    heads: dict[str, HeadResult]
    config: JsonObject
    seeds: dict[str, int]
    versions: dict[str, str | None]
    skipped_heads: dict[str, SkippedHead] = field(default_factory=dict)
    seconds: dict[str, float] = field(default_factory=dict)
    suite: str = "libero_spatial"
    """The LIBERO suite of the episodes (files without it: LIBERO-spatial's)."""
    format: str = FORMAT
    format_version: int = FORMAT_VERSION


# -- conversions -------------------------------------------------------------------------------------------


DECIMALS = 10
"""Decimals kept in the file: enough that a figure quoted at 3 decimals rounds once, from the computed value
(at 5, 0.738496 was stored as 0.7385 and quoted as 0.739 where ``vlaprobe hypotheses`` printed 0.738), and
few enough to drop the float noise of the last bits."""


def nested(x: object) -> Nested:
    """A float array as nested lists, NaN -> None, rounded to :data:`DECIMALS` (ints and bools as they are)."""
    a = np.asarray(x)
    if a.dtype.kind in "iub":
        return a.tolist()
    rounded = np.round(a.astype(np.float64), DECIMALS)
    return np.where(np.isnan(rounded), np.array(None), rounded).tolist()


def level(x: Mapping[str, np.ndarray]) -> Level:
    """A :class:`Level` from one level of :func:`~vlaprobe.probes.metrics.summarize`'s output."""
    count = nested(x["count"]) if "count" in x else None
    return Level(nested(x["value"]), nested(x["low"]), nested(x["high"]), nested(x["defined"]), count)


def number(x: SupportsFloat) -> float | None:
    """One float rounded to :data:`DECIMALS`, NaN -> None."""
    x = float(x)
    return None if math.isnan(x) else round(x, DECIMALS)


def arr(x: Nested | None) -> np.ndarray:
    """Nested lists back to a float array (None -> NaN)."""
    return np.array(x, dtype=float)


def write_evaluation(folder: Path, evaluation: Evaluation) -> Path:
    """Write ``evaluation.json`` atomically; return its path."""
    path = Path(folder) / EVALUATION_FILE
    write_atomic(path, json.dumps(asdict(evaluation), allow_nan=False) + "\n")
    return path


def read_evaluation(folder: str | Path) -> Evaluation:
    """Read ``<folder>/evaluation.json``; a one-line error if it is missing, damaged or of another version."""
    path = Path(folder) / EVALUATION_FILE
    if Path(folder).is_file():
        raise VlaprobeError(
            f"{folder} is a file, not a probe folder; pass the folder written by vlaprobe train"
        )
    if not path.is_file():
        raise VlaprobeError(
            f"no {EVALUATION_FILE} in {folder}; pass the folder written by vlaprobe train (--probes)"
        )
    hint = "run vlaprobe train again"
    data, _ = read_versioned(path, FORMAT, "evaluation", READABLE_VERSIONS, hint)
    evaluation = from_json(Evaluation, data, path, hint)
    for head in evaluation.heads.values():
        for best in (head.best, head.observer_best):
            if best is not None and not best.tied:  # version 3: the best layer is the whole set
                best.tied = [best.layer]
    return evaluation


def read_test_episodes(folder: str | Path) -> list[str]:
    """The held-out test episodes of ``<folder>/evaluation.json`` (read with :func:`read_evaluation`)."""
    return list(read_evaluation(folder).split.test_episodes)
