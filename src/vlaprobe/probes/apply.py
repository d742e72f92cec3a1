"""Applying linear probes to hidden states: the one implementation of ``((x - mean) / std) @ weight + bias``.

Training's evaluation (:meth:`vlaprobe.probes.trainer.LinearProbes.logits`), saved probes
(:meth:`vlaprobe.probes.probeset.ProbeSet.logits`), ``vlaprobe hypotheses``, ``vlaprobe cognition`` and the live
server (both through :class:`vlaprobe.cognition.readout.ProbeReadout`) all call :func:`apply_probes`, so one
step's hidden state gives the same logits, bit for bit, on every path that reads it with the same shapes.
"""

from __future__ import annotations

import numpy as np
import torch


def apply_probes(
    x: torch.Tensor,
    weight: torch.Tensor,
    bias: torch.Tensor,
    mean: torch.Tensor | None = None,
    std: torch.Tensor | None = None,
) -> torch.Tensor:
    """Logits (layers, rows, atoms) of hidden states ``x`` (layers, rows, hidden), float32.

    ``weight`` is (layers, hidden, atoms), ``bias`` (layers, atoms); ``mean`` and ``std`` (layers, hidden) are
    the training split's feature statistics when the probes were fit on standardised features (else None).
    One step at one layer is ``layers = rows = 1``.
    """
    if x.ndim != 3 or weight.ndim != 3 or bias.ndim != 2:
        raise ValueError(
            f"apply_probes needs x (layers, rows, hidden), weight (layers, hidden, atoms), bias (layers, atoms); "
            f"got {tuple(x.shape)}, {tuple(weight.shape)}, {tuple(bias.shape)}"
        )
    x = x.to(weight.device, torch.float32)
    if mean is not None and std is not None:
        x = (x - mean[:, None]) / std[:, None]
    return torch.baddbmm(bias[:, None], x, weight)


def apply_probes_to_rows(
    hidden: torch.Tensor,
    weight: torch.Tensor,
    bias: torch.Tensor,
    mean: torch.Tensor | None = None,
    std: torch.Tensor | None = None,
    rows: np.ndarray | None = None,
    chunk: int = 1024,
) -> torch.Tensor:
    """Logits (layers, rows, atoms), on the CPU, of ``rows`` (default all) of ``hidden`` (layers, steps, hidden)
    on any device or dtype: :func:`apply_probes` on ``chunk`` rows at a time, on the probes' device."""
    index = (
        torch.arange(hidden.shape[1]) if rows is None else torch.as_tensor(np.asarray(rows), dtype=torch.long)
    )
    out = torch.empty((weight.shape[0], len(index), weight.shape[2]))
    with torch.no_grad():
        for start in range(0, len(index), chunk):
            part = index[start : start + chunk]
            x = hidden.index_select(1, part.to(hidden.device))
            out[:, start : start + len(part)] = apply_probes(x, weight, bias, mean, std).cpu()
    return out
