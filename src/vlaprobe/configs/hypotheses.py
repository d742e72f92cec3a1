"""Config of ``vlaprobe hypotheses``: the paper's H1/H2 answered with intervals from a probe folder."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path


@dataclass
class HypothesesConfig:
    """Per head the best, earliest-within-interval and steepest-rise layer; object-minus-action differences with
    a joint bootstrap over test episodes; one sentence per hypothesis. Writes ``hypotheses.json`` into the
    probe folder, where ``vlaprobe report`` finds it."""

    probes: Path = Path("runs/default/probes")
    """Folder written by ``vlaprobe train`` with one train/test split (not k-fold or leave-one-task-out: their
    saved probes are refit on every episode)."""
    store: Path | None = None
    """The activation store the probes were trained on. Default: the one named in the probes' config."""
    bootstrap: int | None = None
    """Resamples of the test episodes (each scores both heads). Default: those of ``vlaprobe train``
    (``evaluation.json``'s bootstrap count), so the curves' intervals are the evaluation's."""
    seed: int | None = None
    """Seed of the resampling. Default: the evaluation's bootstrap seed (the same resamples)."""
    json: bool = False
    """Print the result as JSON instead of the sentences."""


@dataclass
class CompareSplitsConfig:
    """Per head and predicate, the within-task probes next to the leave-one-task-out probes of the same store."""

    within: Path = Path("runs/default/probes")
    """Probe folder trained with the default within-task split."""
    across: Path = Path("runs/default/probes-loto")
    """Probe folder trained with ``--split leave-one-task-out`` on the same store."""
    metric: str = "balanced_accuracy"
    """Metric compared (at each folder's best layer of the head)."""
    json: bool = False
    """Print JSON rows instead of the table."""
