"""Multi-label linear probes for every layer at once: one batched matmul per step, not a loop over layers.

All layers' probes are slices of one weight tensor. A minibatch takes the same steps from every layer,
one ``torch.baddbmm`` gives all logits and one ``torch.bmm`` all weight gradients. The loss is a sum of
independent per-layer, per-atom BCE terms and Adam is elementwise, so this equals training every probe on
its own, only faster. What makes it fast on a CPU:

- the training rows are copied once, shuffled and converted to the compute dtype, into one
  (layers, rows, hidden) tensor; a minibatch is then a contiguous slice (no gather, no conversion) and
  each epoch visits the minibatches in a new random order;
- gradients are the one-line logistic-regression formula, written into preallocated buffers (no autograd,
  no fresh multi-megabyte allocations that page-fault on every step);
- internally the weight is laid out (layers, atoms, hidden), for which the gradient matmul runs fastest;
  :class:`LinearProbes` exposes it as (layers, hidden, atoms);
- few epochs of small minibatches: a linear probe needs many updates, not many passes over the data.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import torch

from vlaprobe.configs.train import ProbeConfig
from vlaprobe.devices import resolve_device


@dataclass
class LinearProbes:
    """Per-layer linear probes: ``logit = ((x - mean) / std) @ weight[layer] + bias[layer]``."""

    weight: torch.Tensor
    """(layers, hidden, atoms) float32."""
    bias: torch.Tensor
    """(layers, atoms) float32."""
    mean: torch.Tensor | None = None
    """(layers, hidden) training-split feature means when standardizing, else None."""
    std: torch.Tensor | None = None
    """(layers, hidden) training-split feature standard deviations when standardizing, else None."""

    def logits(self, hidden: torch.Tensor, rows: np.ndarray | None = None, chunk: int = 1024) -> torch.Tensor:
        """Logits (layers, rows, atoms), on the CPU, of ``rows`` (default all) of ``hidden`` (layers, steps, hidden)."""
        device = self.weight.device
        index = (
            torch.arange(hidden.shape[1])
            if rows is None
            else torch.as_tensor(np.asarray(rows), dtype=torch.long)
        )
        out = torch.empty((self.weight.shape[0], len(index), self.weight.shape[2]))
        with torch.no_grad():
            for start in range(0, len(index), chunk):
                part = index[start : start + chunk]
                x = hidden.index_select(1, part.to(hidden.device)).to(device, torch.float32)
                if self.mean is not None and self.std is not None:
                    x = (x - self.mean[:, None]) / self.std[:, None]
                out[:, start : start + len(part)] = torch.baddbmm(self.bias[:, None], x, self.weight).cpu()
        return out


def _training_matrix(
    hidden: torch.Tensor,
    rows: torch.Tensor,
    dtype: torch.dtype,
    device: torch.device,
    standardize: bool,
    chunk: int = 512,
) -> tuple[torch.Tensor, torch.Tensor | None, torch.Tensor | None]:
    """``hidden[:, rows]`` as one contiguous tensor in ``dtype`` on ``device``, standardized if asked.

    Returns (matrix, mean, std); the statistics (float32, (layers, hidden)) are over exactly these rows.
    """
    num_layers, _, hidden_size = hidden.shape
    out = torch.empty((num_layers, len(rows), hidden_size), dtype=dtype, device=device)
    total = torch.zeros((num_layers, hidden_size), dtype=torch.float64, device=device)
    square = torch.zeros_like(total)
    for start in range(0, len(rows), chunk):
        part = hidden.index_select(1, rows[start : start + chunk].to(hidden.device)).to(device)
        out[:, start : start + len(part[0])].copy_(part)
        if standardize:
            part = part.double()
            total += part.sum(1)
            square += (part * part).sum(1)
    if not standardize:
        return out, None, None
    mean = total / len(rows)
    std = (square / len(rows) - mean * mean).clamp_min(0).sqrt().clamp_min(1e-6)  # constant feature: no 0/0
    mean, std = mean.float(), std.float()
    for start in range(0, len(rows), chunk):
        view = out[:, start : start + chunk]
        view.copy_((view.float() - mean[:, None]) / std[:, None])
    return out, mean, std


def num_epochs(num_rows: int, cfg: ProbeConfig) -> int:
    """Epochs actually run: ``cfg.epochs``, or more if that gives fewer than ``cfg.min_updates`` updates."""
    per_epoch = math.ceil(num_rows / cfg.batch_size)
    return max(cfg.epochs, math.ceil(cfg.min_updates / per_epoch))


def fit_probes(
    hidden: torch.Tensor, targets: np.ndarray, rows: np.ndarray, cfg: ProbeConfig, seed: int
) -> LinearProbes:
    """Train one multi-label probe per layer on ``rows`` of ``hidden`` (layers, steps, hidden).

    ``targets`` is bool/float (steps, atoms) over all steps; only ``rows`` are read. Weights start at zero
    and biases at each atom's log-odds in the training rows, so the first step already predicts the base
    rates. AdamW (plain Adam when ``weight_decay`` is 0) with a cosine learning rate from ``cfg.lr`` to 0
    over :func:`num_epochs` epochs.
    """
    device = resolve_device(cfg.device)
    dtype = torch.bfloat16 if cfg.compute_dtype == "bfloat16" else torch.float32
    generator = torch.Generator().manual_seed(seed)
    rows_np = np.asarray(rows)
    if len(rows_np) == 0:
        raise ValueError("no training rows")
    order = torch.as_tensor(rows_np, dtype=torch.long)[torch.randperm(len(rows_np), generator=generator)]
    x, mean, std = _training_matrix(hidden, order, dtype, device, cfg.standardize)
    y = torch.as_tensor(np.asarray(targets)[order.numpy()], dtype=torch.float32, device=device)
    n, num_atoms = y.shape
    num_layers, _, hidden_size = x.shape

    freq = y.mean(0).clamp(1e-4, 1 - 1e-4)
    pos_weight = (1 - freq) / freq if cfg.balance else None
    weight = torch.zeros((num_layers, num_atoms, hidden_size), device=device, requires_grad=True)
    bias = torch.logit(freq).expand(num_layers, num_atoms).contiguous().requires_grad_(True)
    groups = [{"params": [weight], "weight_decay": cfg.weight_decay}, {"params": [bias], "weight_decay": 0.0}]
    try:  # one fused kernel per step (CPU support since torch 2.4); the weight decay is on weights only
        optimizer = torch.optim.AdamW(groups, lr=cfg.lr, fused=True)
    except RuntimeError:
        optimizer = torch.optim.AdamW(groups, lr=cfg.lr, foreach=True)
    weight.grad = torch.zeros_like(weight)
    bias.grad = torch.zeros_like(bias)
    low_precision_weight = torch.empty_like(weight, dtype=dtype) if dtype != torch.float32 else None

    starts = torch.arange(0, n, cfg.batch_size)
    epochs = num_epochs(n, cfg)
    total_steps = epochs * len(starts)
    step = 0
    with torch.no_grad():
        for _ in range(epochs):
            for start in starts[torch.randperm(len(starts), generator=generator)].tolist():
                xb, yb = x[:, start : start + cfg.batch_size], y[start : start + cfg.batch_size]
                w = weight if low_precision_weight is None else low_precision_weight.copy_(weight)
                logits = torch.baddbmm(bias[:, None].to(dtype), xb, w.transpose(1, 2))
                p = torch.sigmoid(logits.float())
                # d BCE / d logit = p - y; with a positive-class weight c: p (1 + (c - 1) y) - c y.
                grad = p.sub_(yb) if pos_weight is None else p * (1 + (pos_weight - 1) * yb) - pos_weight * yb
                grad /= len(yb)
                if dtype == torch.float32:
                    torch.bmm(grad.transpose(1, 2), xb, out=weight.grad)
                else:
                    weight.grad.copy_(torch.bmm(grad.to(dtype).transpose(1, 2), xb))
                torch.sum(grad, dim=1, out=bias.grad)
                for group in optimizer.param_groups:
                    group["lr"] = cfg.lr * 0.5 * (1 + math.cos(math.pi * step / total_steps))
                optimizer.step()
                step += 1
    return LinearProbes(
        weight=weight.detach().transpose(1, 2).contiguous(), bias=bias.detach(), mean=mean, std=std
    )
