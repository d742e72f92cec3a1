"""Config of ``vlaprobe train``: per-layer linear probes on an activation store."""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Annotated, Literal

import tyro

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
    """Optimisation of the probes: one linear layer per hidden state and head, sigmoid + BCE, Adam."""

    epochs: int = 4
    """Passes over the training steps. At the paper's scale (6,400 training steps) 4 epochs of small batches
    beat the published recipe's 20 epochs of batch 4096 in accuracy at a fifth of its matmul work
    (bench/probe_training.py)."""
    min_updates: int = 200
    """At least this many Adam updates: smaller datasets get more epochs (they are cheap)."""
    batch_size: int = 128
    """Steps per Adam update. A linear probe needs many updates more than many passes over the data."""
    lr: float = 3e-3
    """Peak Adam learning rate, decayed to zero with a cosine over the run (the recipe: 1e-3, constant)."""
    weight_decay: float = 0.0
    """Decoupled (AdamW) weight decay; 0 means plain Adam."""
    balance: bool = False
    """Weight each atom's positives by its negative/positive ratio in the training split (off in the paper)."""
    standardize: bool = False
    """Scale each feature to zero mean and unit variance with training-split statistics (off in the paper)."""
    threshold: float = 0.5
    """Probability above which an atom is predicted true."""
    compute_dtype: Literal["float32", "bfloat16"] = "float32"
    """Matmul precision. bfloat16 is faster where the hardware has it (recent x86, GPUs); weights and the
    optimiser state stay float32 either way."""
    device: str = "auto"
    """Torch device: "auto" picks cuda when available, else cpu."""


@dataclass
class TrainConfig:
    """Train per-layer probes for object and action atoms, evaluate them, and save them."""

    store: Path = Path("runs/default/activations")
    """Activation store written by ``vlaprobe collect``."""
    out: Path | None = None
    """Output folder for probes and evaluation. Default: a ``probes`` folder next to the store."""
    heads: tuple[str, ...] = ("object", "action")
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
    seed: int = 0
    """Seed of the split, probe minibatch order, label shuffling and bootstrap (each derives its own)."""
