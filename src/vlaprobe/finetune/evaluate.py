"""Validation figures, the two OpenVLA reports: action-token accuracy and L1 of the decoded actions."""

from __future__ import annotations

import contextlib
from dataclasses import dataclass

import numpy as np
import torch

from vlaprobe.finetune.examples import ActionStats, Examples, make_batch
from vlaprobe.finetune.objective import label_logits, loss_of
from vlaprobe.policies.openvla.actions import decode_action
from vlaprobe.policies.openvla.model import ACTION_DIM, OpenVLA


@dataclass(frozen=True)
class Validation:
    """Teacher-forced figures on the validation rows."""

    loss: float
    """Mean cross-entropy over the 8 labels (as the training loss)."""
    accuracy: float
    """Share of the 7 action tokens whose argmax over the whole vocabulary is the label (OpenVLA's
    ``action_accuracy``; the stop token is not counted)."""
    l1: float
    """Mean |decoded − true| over the 7 dimensions of the continuous actions, de-normalised with the
    checkpoint's statistics (gripper in [0, 1], 1 open)."""
    l1_normalized: float
    """OpenVLA's logged ``l1_loss``: mean |bin centre of the prediction − bin centre of the label| in [−1, 1]."""
    samples: int
    """Validation rows."""


def autocast(device: torch.device, bf16: bool) -> contextlib.AbstractContextManager[object]:
    """bf16 autocast on CUDA when asked; nothing on the CPU (fp32)."""
    if bf16 and device.type == "cuda":
        return torch.autocast("cuda", dtype=torch.bfloat16)
    return contextlib.nullcontext()


@torch.no_grad()
def validate(
    model: OpenVLA,
    examples: Examples,
    rows: np.ndarray,
    stats: ActionStats,
    device: torch.device,
    batch_size: int,
    bf16: bool = False,
) -> Validation:
    """Figures over ``rows`` (no augmentation), batch by batch."""
    cfg = model.config
    was_training = model.training
    model.eval()
    loss_sum, preds = 0.0, []
    for start in range(0, len(rows), batch_size):
        batch = make_batch(examples, rows[start : start + batch_size], model, device)
        with autocast(device, bf16):
            logits = label_logits(model, batch)
        loss_sum += float(loss_of(logits, batch.labels)) * len(batch.labels)
        preds.append(logits[:, :ACTION_DIM].argmax(-1).cpu().numpy())
    model.train(was_training)
    pred = np.concatenate(preds)
    label = examples.tokens[rows]

    def decode(tokens: np.ndarray, mask: np.ndarray) -> np.ndarray:
        return decode_action(tokens, stats.q01, stats.q99, mask, cfg.action_vocab_end, cfg.n_action_bins)

    unmasked = np.zeros_like(stats.mask)
    return Validation(
        loss=loss_sum / len(rows),
        accuracy=float((pred == label).mean()),
        l1=float(np.abs(decode(pred, stats.mask) - examples.demos.actions[rows]).mean()),
        l1_normalized=float(np.abs(decode(pred, unmasked) - decode(label, unmasked)).mean()),
        samples=len(rows),
    )
