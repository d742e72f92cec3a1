"""Config of ``vlaprobe compare-stores``: stores side by side on the task baselines and their diversity."""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from pathlib import Path
from typing import Annotated

import tyro

from vlaprobe.configs.policy import PolicyConfig


@dataclass
class CompareStoresConfig:
    """Per store and head, from the labels alone: the majority, task and task x time baselines' mean balanced
    accuracy (on the split ``vlaprobe train`` would make, over the atoms it would keep) with 95% intervals,
    distinct state vectors and atoms that change within an episode; each store minus the first."""

    stores: Annotated[tuple[Path, ...], tyro.conf.Positional] = ()
    """Activation stores; the first is the reference (e.g. the fixed-init store), then e.g. a sampled one."""
    names: tuple[str, ...] = ()
    """A short name per store for the table (default: the name of the folder holding each store)."""
    probes: Path | None = None
    """Also write ``store_comparison.json`` into this probe folder, where ``vlaprobe report`` shows it."""
    seed: int = 0
    """Seed of the split (as ``vlaprobe train --seed``) and of the bootstrap resamples."""
    test_fraction: float = 0.2
    """Share of each task's episodes held out, as ``vlaprobe train --split.test-fraction``."""
    min_frequency: float = 0.01
    """Atoms true in fewer training steps are not scored (as ``vlaprobe train``)."""
    max_frequency: float = 0.99
    """Atoms true in more training steps are not scored (as ``vlaprobe train``)."""
    bootstrap: int = 1000
    """Resamples of each store's test episodes for the intervals."""
    success_only: bool = False
    """Only successful episodes (as ``vlaprobe train --split.success-only``)."""
    json: bool = False
    """Print the comparison as JSON instead of the table."""


@dataclass
class ReobserveConfig:
    """Show every episode of a store (its stored images, atoms, actions) to another model and write that model's
    hidden states into a new store: two observers compared on exactly the same episodes, one simulation."""

    store: Annotated[Path, tyro.conf.Positional] = Path("runs/default/activations")
    """The source activation store (collected with its images, as ``vlaprobe collect`` keeps them)."""
    out: Path | None = None
    """The new store (default: ``<source>-<model>`` beside the source, the model's folder name for a path); a rerun resumes it (episodes already copied are kept)."""
    policy: Annotated[PolicyConfig, tyro.conf.OmitArgPrefixes] = dataclasses.field(
        default_factory=PolicyConfig
    )
    """The observer: ``--model`` as ``vlaprobe collect --model`` (a name, a checkpoint folder or a hub id)."""
    batch: int = 16
    """Images per batched prompt pass."""
