"""One reading of a ``--device`` setting, shared by the policies and the probe trainer."""

from __future__ import annotations

import torch

from vlaprobe.errors import VlaprobeError


def resolve_device(name: str) -> torch.device:
    """``auto`` = CUDA when available, else CPU; ``cpu``, ``cuda`` and ``cuda:N`` as given, checked here so
    a wrong name or a missing GPU is a one-line error instead of a torch traceback later."""
    if name == "auto":
        name = "cuda" if torch.cuda.is_available() else "cpu"
    try:
        dev = torch.device(name)
    except RuntimeError:
        raise VlaprobeError(f"unknown device {name!r}; use 'auto', 'cpu', 'cuda' or 'cuda:N'") from None
    if dev.type not in ("cpu", "cuda"):
        raise VlaprobeError(f"unsupported device {name!r}; use 'auto', 'cpu', 'cuda' or 'cuda:N'")
    if dev.type == "cuda" and not torch.cuda.is_available():
        raise VlaprobeError(f"device {name!r} requested but CUDA is not available; use 'cpu' or 'auto'")
    return dev
