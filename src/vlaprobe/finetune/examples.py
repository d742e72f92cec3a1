"""Rows → model batches: prompt ids per episode, action token ids per row, optional cached patch features."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch

from vlaprobe.finetune.data import Demonstrations
from vlaprobe.finetune.objective import Batch, pixel_batch, sequences
from vlaprobe.policies.openvla.actions import encode_action, normalize_action
from vlaprobe.policies.openvla.model import ACTION_DIM, OpenVLA
from vlaprobe.policies.openvla.tokenizer import Tokenizer, prompt_ids


@dataclass(frozen=True)
class ActionStats:
    """The action statistics the tokens are binned with (``norm_stats[name]["action"]``)."""

    q01: np.ndarray
    q99: np.ndarray
    mask: np.ndarray


@dataclass
class Examples:
    """Everything a batch is built from."""

    demos: Demonstrations
    """The rows."""
    tokens: np.ndarray
    """int64 (N, 7): each row's action as OpenVLA's action token ids."""
    prompts: list[list[int]]
    """Prompt ids per episode (ending with the empty token, as the policy feeds them)."""
    features: torch.Tensor | None
    """(N, P, V) float16 fused-backbone patch features when the featurisers are frozen, else None."""
    width: int | None = None
    """Sequence length every batch is right-padded to (the longest prompt + 7), or None: each batch's own."""


def make_examples(
    demos: Demonstrations, tokenizer: Tokenizer, stats: ActionStats, model: OpenVLA
) -> Examples:
    """Token ids of every row's action (binned with ``stats``) and the prompt ids of every episode."""
    cfg = model.config
    normalized = normalize_action(demos.actions, stats.q01, stats.q99, stats.mask)
    tokens = encode_action(normalized, cfg.action_vocab_end, cfg.n_action_bins)
    prompts = [prompt_ids(tokenizer, ref.instruction) for ref in demos.episodes]
    return Examples(demos, tokens, prompts, None)


@torch.no_grad()
def cache_features(examples: Examples, model: OpenVLA, device: torch.device, batch_size: int = 64) -> None:
    """Run the frozen featurisers once over every image; later batches read the cached features."""
    images = examples.demos.images
    out = []
    for start in range(0, len(images), batch_size):
        pv = pixel_batch(images[start : start + batch_size], model.config, device)
        out.append(model.vision_backbone(pv.to(model.projector.fc1.weight.dtype)).to(torch.float16).cpu())
    examples.features = torch.cat(out)


def longest_sequence(examples: Examples) -> int:
    """Ids of the longest training sequence: the longest prompt + the 7 action tokens (``Examples.width``)."""
    return max(len(p) for p in examples.prompts) + ACTION_DIM


def make_batch(
    examples: Examples,
    rows: np.ndarray,
    model: OpenVLA,
    device: torch.device,
    rng: np.random.Generator | None = None,
    crop_scale: float = 0.9,
) -> Batch:
    """The batch of ``rows``; images augmented with ``rng`` when given (never with cached features)."""
    cfg = model.config
    prompts = [examples.prompts[e] for e in examples.demos.episode[rows]]
    ids, positions, labels = sequences(prompts, examples.tokens[rows], cfg, examples.width)
    if examples.features is not None:
        inputs = examples.features[torch.from_numpy(rows)].to(device)
    else:
        inputs = pixel_batch(examples.demos.images[rows], cfg, device, rng, crop_scale)
    return Batch(
        inputs, examples.features is not None, ids.to(device), positions.to(device), labels.to(device)
    )


def majority_accuracy(tokens: np.ndarray, train: np.ndarray, val: np.ndarray) -> float:
    """Validation token accuracy of always predicting each dimension's most frequent training token."""
    correct = 0
    for d in range(tokens.shape[1]):
        values, counts = np.unique(tokens[train, d], return_counts=True)
        correct += int((tokens[val, d] == values[np.argmax(counts)]).sum())
    return correct / (len(val) * tokens.shape[1])
