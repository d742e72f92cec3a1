"""Config of ``vlaprobe cross-suite``: probes trained on one LIBERO suite scored on another suite's store."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path


@dataclass
class CrossSuiteConfig:
    """Apply a probe folder trained on one suite to every episode of an activation store of another suite, over
    the atoms both vocabularies share (by name) and the layers both have: per head the balanced accuracy per
    layer with a 95% interval over the store's episodes, the best layer and the layers tied with it, per atom
    family at the best layer, against the majority and a time-only baseline fit on the probes' own store, the
    shuffled-label control and, with --control-probes/--control-store, the control observer.
    Writes ``cross_suite.json`` (or --out) and prints a table."""

    probes: Path = Path("runs/default/probes")
    """Probe folder written by ``vlaprobe train`` on the source suite (its ``probes.json`` names the suite)."""
    store: Path = Path("runs/goal/activations")
    """Activation store of the target suite (``vlaprobe collect --suite ...``), observed by the same model with
    the same pooling. Every episode is scored: none of them was seen in training."""
    source_store: Path | None = None
    """The store the probes were trained on, whose labels fit the time-only baseline. Default: the one named in
    the probes' ``probes.json``."""
    out: Path | None = None
    """Where to write the result. Default: ``cross_suite_<target suite>.json`` in the probe folder."""
    bootstrap: int = 1000
    """Resamples of the target store's episodes for the intervals (at least 10)."""
    seed: int = 0
    """Seed of the resamples."""
    success_only: bool = False
    """Score only the target store's successful episodes."""
    assets: Path | None = None
    """LIBERO assets folder, to read which atoms each task of both suites defines from its BDDL scene. Default:
    $VLAPROBE_LIBERO_ASSETS, else the installed libero package's."""
    shuffled_control: bool = True
    """Also fit probes on the source store's training rows with their labels permuted across steps (as ``vlaprobe
    train``'s shuffled-label control: the same rows, seed and C), at the probes' own best layer and the target's
    best layer, and score them on the target rows: what the probes must beat."""
    shuffled_permutations: int = 5
    """Label permutations of that control (its figure is their mean; ``vlaprobe train``'s default count)."""
    control_probes: Path | None = None
    """Probe folder trained on the control observer's (e.g. the untrained network's) store of the source suite
    (``control-probes`` of ``vlaprobe run``): scored on --control-store, compared with the probes (paired)."""
    control_store: Path | None = None
    """The target suite's store observed by the control observer: the same episodes as --store."""
    json: bool = False
    """Print the result as JSON instead of the table."""
