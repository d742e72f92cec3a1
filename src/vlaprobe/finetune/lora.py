"""LoRA through peft on our OpenVLA module: OpenVLA's recipe (every linear layer but ``lm_head``, alpha =
min(rank, 16), gaussian init), merged weights for the checkpoint, adapter weights for resuming.

Our network is a plain ``nn.Module``, not a transformers ``PreTrainedModel``, so peft's ``"all-linear"``
shortcut is spelled out: the targets are the full names of every ``nn.Linear`` except the output layer,
which is what "all-linear" selects on OpenVLA's own model.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import torch
from torch import nn

from vlaprobe.files import JsonObject
from vlaprobe.policies.openvla.model import OpenVLA

if TYPE_CHECKING:
    from peft import LoraConfig

ADAPTER = "default"
"""peft's adapter name."""
PEFT_PREFIX = "base_model.model."
"""Prefix of the keys in peft's saved ``adapter_model.safetensors``."""


def lora_targets(model: nn.Module) -> list[str]:
    """Full names of the linear layers LoRA adapts ("all-linear": every ``nn.Linear`` but ``lm_head``)."""
    return sorted(
        name
        for name, module in model.named_modules()
        if isinstance(module, nn.Linear) and not name.endswith("lm_head")
    )


def lora_config(model: nn.Module, rank: int, dropout: float) -> LoraConfig:
    """peft's ``LoraConfig`` for OpenVLA's fine-tuning recipe."""
    from peft import LoraConfig

    return LoraConfig(
        r=rank,
        lora_alpha=min(rank, 16),
        lora_dropout=dropout,
        target_modules=lora_targets(model),
        init_lora_weights="gaussian",
    )


def add_lora(model: OpenVLA, rank: int, dropout: float, seed: int) -> LoraConfig:
    """Inject the adapters in place (A drawn from ``seed``, B = 0) and leave only them trainable."""
    from peft import inject_adapter_in_model

    config = lora_config(model, rank, dropout)
    with torch.random.fork_rng(devices=[]):
        torch.manual_seed(seed)
        inject_adapter_in_model(config, model, adapter_name=ADAPTER)
    for name, p in model.named_parameters():
        p.requires_grad_("lora_" in name)
    return config


def _lora_layers(model: nn.Module) -> JsonObject:
    from peft.tuners.lora import LoraLayer

    return {name: m for name, m in model.named_modules() if isinstance(m, LoraLayer)}


@torch.no_grad()
def merged_state_dict(model: nn.Module) -> dict[str, torch.Tensor]:
    """The base names and shapes with each adapted weight replaced by W + scale·B·A (float32, on the CPU)."""
    layers = _lora_layers(model)
    out: dict[str, torch.Tensor] = {}
    for key, value in model.state_dict().items():
        if "lora_" in key:
            continue
        name = key.replace(".base_layer.", ".")
        owner = name.rsplit(".", 1)[0]
        tensor = value.detach().to("cpu", torch.float32)
        if owner in layers and name.endswith(".weight"):
            tensor = tensor + layers[owner].get_delta_weight(ADAPTER).detach().to("cpu", torch.float32)
        out[name] = tensor.contiguous()
    return out


def adapter_state_dict(model: nn.Module) -> dict[str, torch.Tensor]:
    """The adapter weights under peft's saved names (``base_model.model.<module>.lora_A.weight``)."""
    return {
        PEFT_PREFIX + key.replace(f".{ADAPTER}.", "."): value.detach().to("cpu", torch.float32).contiguous()
        for key, value in model.state_dict().items()
        if "lora_" in key
    }


def load_adapter(model: nn.Module, tensors: dict[str, torch.Tensor]) -> None:
    """Copy saved adapter weights (peft's names) into the injected adapters; every one must match."""
    own = {k: v for k, v in model.state_dict().items() if "lora_" in k}
    renamed = {}
    for key, value in tensors.items():
        name = key.removeprefix(PEFT_PREFIX)
        for part in ("lora_A", "lora_B"):
            name = name.replace(f".{part}.", f".{part}.{ADAPTER}.")
        renamed[name] = value
    if set(renamed) != set(own):
        raise ValueError(f"adapter keys differ: {sorted(set(renamed) ^ set(own))[:3]}")
    for key, value in renamed.items():
        own[key].copy_(value)


def adapter_config_json(config: LoraConfig) -> JsonObject:
    """peft's ``adapter_config.json`` content (sets as sorted lists)."""
    out = {}
    for key, value in config.to_dict().items():
        if isinstance(value, set):
            value = sorted(value)
        out[key] = value.value if hasattr(value, "value") else value
    return out
