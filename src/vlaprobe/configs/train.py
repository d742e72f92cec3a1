"""Config of ``vlaprobe train``: per-layer linear probes on an activation store."""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Annotated, Literal

import tyro

from vlaprobe.symbols import HEADS

Metric = Literal["accuracy", "balanced_accuracy", "f1", "auprc"]


@dataclass
class SplitConfig:
    """How steps are divided into training and test data: always by whole episode."""

    test_fraction: float = 0.2
    """Share of each task's episodes held out for testing (at least one per task that has two or more)."""
    folds: int = 1
    """1: one train/test split. k >= 2: k-fold cross-validation grouped by episode and stratified by task;
    every episode is tested once, the figures pool all folds, and the saved probes are refit on all episodes."""
    success_only: bool = False
    """Use only the episodes in which the task was completed."""
    by: Annotated[
        Literal["episode", "leave-one-task-out"], tyro.conf.arg(name="split", prefix_name=False)
    ] = "episode"
    """``--split leave-one-task-out``: one fold per task, trained on the other tasks' episodes and tested on its
    own (cross-task generalisation; --split.folds and --split.test-fraction are then unused). The label filter
    keeps the atoms that vary in every fold's training split; the saved probes are refit on all episodes.
    Default "episode": the within-task split above."""


@dataclass
class ProbeConfig:
    """The probes: per hidden state and head, one L2-regularised logistic regression per atom, fit to convergence."""

    standardize: bool = True
    """Scale each feature to zero mean and unit variance with training-split statistics (saved with the probes
    and applied at readout). Without it the layers' very different activation scales decide the fit."""
    c_grid: tuple[float, ...] = (1e-4, 1e-3, 1e-2, 0.1, 1.0, 10.0, 100.0)
    """Inverse L2 strengths C (scikit-learn's convention: penalty ||w||^2 / 2 against C x summed log-loss) from
    which episode-grouped cross-validation on the training split picks one per layer and head: the highest
    mean held-out balanced accuracy over the head's atoms and the folds, the smallest C within
    --probe.c-tolerance of it. A choice at either end of the grid is warned about (``fit.c_at_edge``): widen
    the grid. One value: no cross-validation."""
    c_tolerance: float = 0.005
    """C's whose cross-validated balanced accuracy is within this of the best one tie; the strongest penalty
    (smallest C) of them is chosen."""
    cv_folds: int = 3
    """Folds of that cross-validation, by whole training episodes, stratified by task (only tasks with at
    least 2 training episodes are held out, so the folds ask what the test split asks; whole tasks with
    --split leave-one-task-out)."""
    c_without_cv: float = 1.0
    """C where the training split leaves nothing to hold out (one training episode per task, or one task
    under leave-one-task-out): scikit-learn's default, with a warning."""
    tol: float = 1e-4
    """A probe is converged when the largest absolute entry of its objective's gradient is at most this."""
    max_iter: int = 500
    """L-BFGS iteration cap per probe; probes stopped there are counted and warned about."""
    history: int = 10
    """L-BFGS memory (correction pairs kept per probe)."""
    memory_mb: float = 1024
    """Working memory budget of the solver on an accelerator, where layers are solved in chunks that fit it
    (on a CPU one layer at a time, so that stopped probes leave the working set per layer)."""
    balance: bool = False
    """Weight each atom's positives by its negative/positive ratio in the training split (off in the paper)."""
    threshold: float = 0.5
    """Probability above which an atom is predicted true."""
    device: str = "auto"
    """Torch device: "auto" picks cuda when available, else cpu."""


@dataclass
class TrainConfig:
    """Train per-layer probes for object and action atoms, evaluate them, and save them."""

    store: Path = Path("runs/default/activations")
    """Activation store written by ``vlaprobe collect``."""
    out: Path | None = None
    """Output folder for probes and evaluation. Default: a ``probes`` folder next to the store."""
    heads: tuple[str, ...] = HEADS
    """Label heads to probe (the store's ``atom_names`` keys)."""
    layers: tuple[int, ...] = ()
    """Hidden-state indices to probe (0 = embeddings). Empty: all of them."""
    min_frequency: float = 0.01
    """Atoms true in less than this share of training steps are dropped (too rare to learn or score)."""
    max_frequency: float = 0.99
    """Atoms true in more than this share of training steps are dropped (nearly constant)."""
    split: SplitConfig = field(default_factory=SplitConfig)
    """Train/test division."""
    probe: ProbeConfig = field(default_factory=ProbeConfig)
    """Probe optimisation."""
    shuffled_control: bool = True
    """Also train probes on shuffled training labels (same steps, labels permuted across steps) to measure
    selectivity = accuracy - control accuracy."""
    shuffled_permutations: int = 5
    """Label permutations trained for the shuffled-label control (extra columns of the same matmuls, so cheap):
    the report shows their mean and spread, and selectivity is measured against the mean."""
    observer_store: Path | None = None
    """Optional second store of the same kind (e.g. a randomly initialised model observing the same
    episodes), trained and evaluated the same way as a control."""
    select_metric: Metric = "balanced_accuracy"
    """Metric whose mean over a head's kept atoms picks that head's best layer on the held-out data."""
    bootstrap: int = 1000
    """Bootstrap resamples of test episodes for the 95% intervals of accuracy, balanced accuracy and F1."""
    auprc_bootstrap: int = 100
    """Resamples for the AUPRC intervals (costlier: scores are re-ranked per resample); 0 skips them."""
    conditional: bool = False
    """Conditional probing (``--conditional``): per layer and head, probes on the task and the task x time
    one-hot cells (unpenalised) with and without the standardised hidden state (penalised with the probes' C),
    same split and intervals; the gain is what the layer adds beyond the baseline (``conditional_task``,
    ``conditional_task_time`` in ``evaluation.json``). Off by default in ``vlaprobe train`` (docs/probing.md)."""
    seed: int = 0
    """Seed of the split, probe minibatch order, label shuffling and bootstrap (each derives its own)."""
