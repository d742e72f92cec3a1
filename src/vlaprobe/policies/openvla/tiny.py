"""The tiny OpenVLA: the same network with small widths, built deterministically from a seed.

Same structure and token layout as OpenVLA-7B (DINOv2-with-registers + SigLIP ViTs on 16×16 patches of a
224 px image, concatenated, the 3-layer projector, a 32-layer Llama decoder with 33 hidden states, the
32064-id vocabulary whose last 256 text ids are action bins), sized so one policy step takes about 100 ms
on a laptop CPU. Its weights are random: the hidden states still carry the image and the instruction
(the network is a fixed random feature map of them), which is what the probing pipeline needs to run.
"""

from __future__ import annotations

import math

import torch

from vlaprobe.policies.openvla.config import LlamaDims, OpenVLAConfig, ViTConfig
from vlaprobe.policies.openvla.model import OpenVLA
from vlaprobe.policies.openvla.tokenizer import ACTION_ID_RANGE

TINY_HIDDEN_SIZE = 64
"""Width of the tiny decoder (and of every captured hidden state)."""

LIBERO_SPATIAL_LIKE_STATS = {
    "libero_spatial": {
        "action": {
            "q01": [-0.7454, -0.6616, -0.9375, -0.1071, -0.2068, -0.1843, 0.0],
            "q99": [0.9375, 0.8759, 0.9321, 0.1039, 0.1768, 0.1457, 1.0],
            "mask": [True, True, True, True, True, True, False],
        }
    }
}
"""Action statistics of LIBERO-spatial's scale, so the tiny model's actions have realistic magnitudes."""


def tiny_config(hidden_size: int = TINY_HIDDEN_SIZE, patch_size: int = 14) -> OpenVLAConfig:
    """The tiny architecture: 64-wide ViTs (4 and 3 blocks) on ``patch_size`` patches of the 224 px image
    (14: 256 patches as in OpenVLA; 28: 64, the trained default's shape) and a 32-layer decoder of
    ``hidden_size``."""
    heads = max(1, hidden_size // 32)
    return OpenVLAConfig(
        featurizer=ViTConfig(
            embed_dim=64,
            depth=4,
            num_heads=4,
            mlp_hidden=256,
            class_token=True,
            reg_tokens=4,
            layer_scale=True,
            patch_size=patch_size,
        ),
        fused_featurizer=ViTConfig(
            embed_dim=64, depth=3, num_heads=4, mlp_hidden=239, map_head=True, patch_size=patch_size
        ),
        text=LlamaDims(
            hidden_size=hidden_size,
            intermediate_size=3 * hidden_size,
            num_hidden_layers=32,
            num_attention_heads=heads,
            num_key_value_heads=heads,
        ),
    )


def tiny_state_dict(
    cfg: OpenVLAConfig,
    seed: int,
    device: torch.device | str = "cpu",
    dtype: torch.dtype = torch.float32,
) -> dict[str, torch.Tensor]:
    """Deterministic weights for ``cfg`` from ``seed`` (on the CPU: the same on every machine and torch build).

    ``device``/``dtype``: draw on that device and store in that dtype (``bench/gpu.py`` draws OpenVLA-7B's
    7.5 B random weights on the GPU in bf16; the CPU default is the float32 the tiny models are built from).
    One generator visits the parameters in sorted name order: norms 1 + 0.1·N, biases 0.1·N,
    linear/conv weights N/√fan_in, token embeddings N, LayerScale U(0.3, 1), positional embeddings 0.5·N,
    CLS/register/latent tokens N; the lm_head rows of the 256 action ids are then scaled ×3 so greedy
    decoding over the full vocabulary lands on action tokens, as in a trained OpenVLA.
    """
    with torch.device("meta"):
        shapes = {k: tuple(v.shape) for k, v in OpenVLA(cfg).state_dict().items()}
    gen = torch.Generator(device=device).manual_seed(seed)
    out: dict[str, torch.Tensor] = {}
    for name in sorted(shapes):
        shape = shapes[name]
        normal = torch.randn(shape, generator=gen, dtype=torch.float32, device=device)
        leaf = name.rsplit(".", 1)[-1]
        if leaf == "scale_factor":
            value = 0.3 + 0.7 * torch.rand(shape, generator=gen, dtype=torch.float32, device=device)
        elif leaf == "pos_embed":
            value = 0.5 * normal
        elif leaf in ("cls_token", "reg_token", "latent") or name.endswith("embed_tokens.weight"):
            value = normal
        elif leaf == "bias":
            value = 0.1 * normal
        elif len(shape) == 1:  # LayerNorm / RMSNorm weights
            value = 1.0 + 0.1 * normal
        else:
            value = normal / math.sqrt(math.prod(shape[1:]))
        out[name] = value.to(dtype)
    out["language_model.lm_head.weight"][ACTION_ID_RANGE[0] : ACTION_ID_RANGE[1]] *= 3.0
    return out
