"""Reading a --device setting: one-line errors instead of torch tracebacks."""

from __future__ import annotations

import pytest
import torch

from vlaprobe.devices import resolve_device
from vlaprobe.errors import VlaprobeError


def test_auto_and_cpu() -> None:
    assert resolve_device("auto").type == ("cuda" if torch.cuda.is_available() else "cpu")
    assert resolve_device("cpu") == torch.device("cpu")


@pytest.mark.parametrize(
    ("name", "message"), [("gpu", "unknown device 'gpu'"), ("meta", "unsupported device 'meta'")]
)
def test_bad_names(name: str, message: str) -> None:
    with pytest.raises(VlaprobeError, match=message):
        resolve_device(name)


@pytest.mark.skipif(torch.cuda.is_available(), reason="needs a machine without CUDA")
def test_cuda_without_a_gpu() -> None:
    with pytest.raises(VlaprobeError, match="CUDA is not available"):
        resolve_device("cuda:0")
