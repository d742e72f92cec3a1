"""Config of ``vlaprobe failures`` (failure prediction with conformal alarms on stored episodes)."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path


@dataclass
class FailuresConfig:
    """Predict each stored episode's failure step by step: the cognition, a hidden-state failure probe and the
    time and task × time baselines, with alarms from functional conformal prediction on successes."""

    store: Path = Path("runs/failures/activations")
    """Activation store with failed and successful episodes of one driver (`vlaprobe collect --keep-failed
    --expert-faults ...`)."""
    out: Path = Path("runs/failures/failures")
    """Folder for failures.json."""
    probes: Path | None = None
    """Probe folder (`vlaprobe train`): the cognition reads the probes' predictions of each step. Default: the
    stored ground-truth atoms (the cognition with perfect perception)."""
    layer: int | None = None
    """Layer of the hidden-state failure probe. Default: the middle layer."""
    token_model: str | None = None
    """Score token uncertainty: recompute every stored step's action-token distribution from the stored images
    with this model, which must be the store's observer (its model_id, e.g. "tiny-libero"; see `vlaprobe info`).
    Default: not scored (the store keeps the chosen token ids, not their probabilities)."""
    alpha: float = 0.1
    """Target false-alarm rate: the share of successful episodes the conformal band lets alarm."""
    folds: int = 5
    """Episode folds: each fold is predicted by predictors fitted on the others, its band calibrated on the
    other folds' successful episodes."""
    bootstrap: int = 1000
    """Episode bootstrap resamples of every interval."""
    seed: int = 0
    """Seed of the folds and the bootstrap."""
    json: bool = False
    """Print the figures as one JSON object on stdout."""
