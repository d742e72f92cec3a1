"""OpenVLA's fine-tuning objective: cross-entropy of the 7 action tokens and the stop token, teacher forced.

One training sequence is the policy's own layout with the ground-truth action appended::

    position  0     1 … P      P+1 … T−1                   T … T+6
              <s>   patches    prompt tokens (last 29871)   action tokens 0 … 6      (label after 6: </s>)

The state at T−1+k predicts label k (action token k for k < 7, then </s>), exactly the labels OpenVLA's
collator leaves unmasked. Only these 8 states go through ``lm_head``: the loss never reads the logits of
the ~290 other positions, so they are not computed. Prompts of different lengths are right-padded; the
attention is causal, so padding after a sequence's last label cannot change its logits.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
import torch
import torch.nn.functional as F

from vlaprobe.finetune.augment import augment
from vlaprobe.policies.openvla.config import OpenVLAConfig
from vlaprobe.policies.openvla.model import ACTION_DIM, OpenVLA

LABELS = ACTION_DIM + 1
"""Labelled positions per sequence: the 7 action tokens and the stop token."""


@dataclass
class Batch:
    """Model inputs and labels of one batch, on the training device."""

    inputs: torch.Tensor
    """(B, 6, S, S) pixel values, or (B, P, V) cached patch features of the fused backbone."""
    features: bool
    """Whether ``inputs`` are cached features."""
    input_ids: torch.Tensor
    """(B, L) prompt ids + the 7 action ids, right-padded with the pad id."""
    positions: torch.Tensor
    """(B, 8) positions in the full sequence (patches included) whose states predict the labels."""
    labels: torch.Tensor
    """(B, 8) the 7 action token ids then the stop id."""


def pixel_batch(
    images: np.ndarray,
    cfg: OpenVLAConfig,
    device: torch.device,
    rng: np.random.Generator | None = None,
    crop_scale: float = 0.9,
) -> torch.Tensor:
    """(B, S, S, 3) uint8 → (B, 6, S, S) float32 pixel values; augmented when ``rng`` is given.

    Without augmentation this is :func:`vlaprobe.policies.openvla.preprocessing.pixel_values` batched (the
    same float32 operations, bit for bit), so training sees what the policy sees.
    """
    x = torch.from_numpy(np.ascontiguousarray(images)).to(device).permute(0, 3, 1, 2).float() / 255.0
    if rng is not None:
        x = augment(x, rng, crop_scale)
    chans = []
    for mean, std in zip(cfg.image_means, cfg.image_stds, strict=True):
        m = torch.tensor(mean, dtype=torch.float32, device=device).view(1, 3, 1, 1)
        s = torch.tensor(std, dtype=torch.float32, device=device).view(1, 3, 1, 1)
        chans.append((x - m) / s)
    return torch.cat(chans, dim=1)


def sequences(
    prompts: list[list[int]], tokens: np.ndarray, cfg: OpenVLAConfig, width: int | None = None
) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """(input_ids (B, L), positions (B, 8), labels (B, 8)) for prompt ids and (B, 7) action token ids.

    L is the longest prompt + 7, or ``width`` when given (one shape for every batch of a compiled step).
    """
    longest = max(len(p) for p in prompts) + ACTION_DIM
    if width is not None and width < longest:
        raise ValueError(f"width {width} is shorter than the batch's longest sequence ({longest})")
    width = longest if width is None else width
    ids = torch.full((len(prompts), width), cfg.text.pad_token_id, dtype=torch.long)
    positions = torch.empty((len(prompts), LABELS), dtype=torch.long)
    for i, prompt in enumerate(prompts):
        n = len(prompt)
        ids[i, :n] = torch.tensor(prompt)
        ids[i, n : n + ACTION_DIM] = torch.from_numpy(tokens[i])
        last_prompt = n - 1 + cfg.num_patches  # the patches sit between <s> and the prompt's second id
        positions[i] = torch.arange(last_prompt, last_prompt + LABELS)
    eos = np.full((len(prompts), 1), cfg.text.eos_token_id, dtype=np.int64)
    labels = torch.from_numpy(np.concatenate([tokens.astype(np.int64), eos], axis=1))
    return ids, positions, labels


def label_logits(model: OpenVLA, batch: Batch) -> torch.Tensor:
    """(B, 8, vocab) logits at the labelled positions only (the full vocabulary, as OpenVLA's loss)."""
    if batch.features:
        embeds = model.embed_features(batch.inputs, batch.input_ids)
    else:
        embeds = model.embed(batch.inputs, batch.input_ids)
    hidden = model.language_model.model(inputs_embeds=embeds, use_cache=False).last_hidden_state
    index = batch.positions.unsqueeze(-1).expand(-1, -1, hidden.shape[-1])
    return model.language_model.lm_head(hidden.gather(1, index))


def loss_of(logits: torch.Tensor, labels: torch.Tensor) -> torch.Tensor:
    """Mean next-token cross-entropy over the 8 labels of every sequence (in float32)."""
    return F.cross_entropy(logits.float().flatten(0, 1), labels.flatten())


StepForward = Callable[[Batch], tuple[torch.Tensor, torch.Tensor]]
"""A batch → (its label logits (B, 8, vocab), its loss): the forward a training step differentiates."""


def step_forward(model: OpenVLA, compile: bool = False) -> StepForward:
    """The training step's forward, compiled with ``torch.compile`` (inductor) when asked.

    The compiled graph holds the model's whole forward and the loss; autograd runs its compiled backward.
    Batches must keep one shape (``Examples.width``), or every new sequence length compiles again.
    """

    def forward(batch: Batch) -> tuple[torch.Tensor, torch.Tensor]:
        logits = label_logits(model, batch)
        return logits, loss_of(logits, batch.labels)

    return torch.compile(forward, dynamic=False) if compile else forward
