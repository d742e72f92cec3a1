"""Architecture of an OpenVLA model: two ViT featurizers, the fused projector, a Llama decoder.

One dataclass tree describes both the released OpenVLA-7B (``openvla_7b()``) and the tiny CPU model
(``tiny_config()``); :mod:`vlaprobe.policies.openvla.checkpoint` reads it from an official ``config.json``
(``from_official``) and writes it back (``to_official``).
"""

from __future__ import annotations

import dataclasses
import json
from dataclasses import dataclass, field

from vlaprobe.errors import VlaprobeError
from vlaprobe.files import JsonObject

SUPPORTED_VISION_BACKBONE = "dinosiglip-vit-so-224px"
"""The only vision backbone id every released OpenVLA checkpoint uses (DINOv2 + SigLIP, 224 px)."""


def _check_dims(cfg: object, names: tuple[str, ...]) -> None:
    """Model sizes read from a checkpoint's config.json must be positive integers (one-line error)."""
    for name in names:
        value = getattr(cfg, name)
        if isinstance(value, bool) or not isinstance(value, int) or value < 1:
            raise VlaprobeError(
                f"model config: {type(cfg).__name__}.{name} must be a positive integer, got {value!r}; "
                "fix the checkpoint's config.json"
            )


def _check_divides(part: int, whole: int, part_name: str, whole_name: str) -> None:
    if whole % part:
        raise VlaprobeError(
            f"model config: {whole_name} {whole} is not a multiple of {part_name} {part}; fix the checkpoint's config.json"
        )


@dataclass
class ViTConfig:
    """One timm-style vision transformer featurizer (parameter names as timm 0.9 writes them)."""

    embed_dim: int
    """Token width."""
    depth: int
    """Number of blocks. OpenVLA reads the tokens after block ``depth - 2`` (the second-to-last)."""
    num_heads: int
    """Attention heads (head dim = embed_dim / num_heads)."""
    mlp_hidden: int
    """Hidden width of each block's MLP."""
    class_token: bool = False
    """A learned CLS token is prepended (DINOv2)."""
    reg_tokens: int = 0
    """Learned register tokens after the CLS token (DINOv2 "reg4": 4)."""
    layer_scale: bool = False
    """Per-channel LayerScale on both residual branches, stored as ``ls1/ls2.scale_factor``."""
    map_head: bool = False
    """The checkpoint holds a MAP attention-pool head ``attn_pool.*`` (SigLIP); OpenVLA never runs it."""
    patch_size: int = 14
    """Square patch side in pixels."""
    image_size: int = 224
    """Square input side in pixels."""
    norm_eps: float = 1e-6
    """LayerNorm epsilon."""

    def __post_init__(self) -> None:
        _check_dims(self, ("embed_dim", "depth", "num_heads", "mlp_hidden", "patch_size", "image_size"))
        _check_divides(self.num_heads, self.embed_dim, "num_heads", "embed_dim")

    @property
    def num_patches(self) -> int:
        return (self.image_size // self.patch_size) ** 2

    @property
    def num_prefix_tokens(self) -> int:
        return int(self.class_token) + self.reg_tokens


TIMM_PRESETS: dict[str, ViTConfig] = {
    "vit_large_patch14_reg4_dinov2.lvd142m": ViTConfig(
        embed_dim=1024,
        depth=24,
        num_heads=16,
        mlp_hidden=4096,
        class_token=True,
        reg_tokens=4,
        layer_scale=True,
    ),
    "vit_so400m_patch14_siglip_224": ViTConfig(
        embed_dim=1152, depth=27, num_heads=16, mlp_hidden=4304, map_head=True
    ),
}
"""timm 0.9.10's definitions of OpenVLA's two featurizers at 224 px (``dinosiglip-vit-so-224px``)."""


@dataclass
class LlamaDims:
    """The Llama-2 decoder (transformers' ``LlamaConfig`` fields OpenVLA sets or relies on)."""

    hidden_size: int = 4096
    """Residual width; also the width of every captured hidden state."""
    intermediate_size: int = 11008
    """SwiGLU MLP width."""
    num_hidden_layers: int = 32
    """Decoder layers; the model yields num_hidden_layers + 1 hidden states."""
    num_attention_heads: int = 32
    """Query heads."""
    num_key_value_heads: int = 32
    """Key/value heads (equal to the query heads: no GQA in Llama-2-7B)."""
    vocab_size: int = 32064
    """32000 Llama tokens + 1 pad token, padded to a multiple of 64."""
    rms_norm_eps: float = 1e-6
    """RMSNorm epsilon: the LlamaConfig default OpenVLA keeps (not Llama-2's 1e-5)."""
    rope_theta: float = 10000.0
    """RoPE base."""
    max_position_embeddings: int = 2048
    """Longest sequence (OpenVLA's ``llm_max_length``)."""
    pad_token_id: int = 32000
    """The ``<PAD>`` token OpenVLA added."""
    bos_token_id: int = 1
    """Llama's ``<s>``."""
    eos_token_id: int = 2
    """Llama's ``</s>``: greedy decoding stops there, as transformers' ``generate`` does."""

    def __post_init__(self) -> None:
        _check_dims(
            self,
            (
                "hidden_size",
                "intermediate_size",
                "num_hidden_layers",
                "num_attention_heads",
                "num_key_value_heads",
                "vocab_size",
            ),
        )
        _check_divides(self.num_attention_heads, self.hidden_size, "num_attention_heads", "hidden_size")
        _check_divides(
            self.num_key_value_heads, self.num_attention_heads, "num_key_value_heads", "num_attention_heads"
        )


@dataclass
class OpenVLAConfig:
    """Everything needed to build the network and decode its actions."""

    featurizer: ViTConfig
    """DINOv2 branch (pixel channels 0–2)."""
    fused_featurizer: ViTConfig
    """SigLIP branch (pixel channels 3–5)."""
    text: LlamaDims = field(default_factory=LlamaDims)
    """The Llama decoder."""
    n_action_bins: int = 256
    """Action bins: the last n_action_bins ids of the unpadded vocabulary."""
    pad_to_multiple_of: int = 64
    """Vocabulary padding; the action ids count back from vocab_size - pad_to_multiple_of = 32000."""
    image_means: tuple[tuple[float, float, float], ...] = ((0.484375, 0.455078125, 0.40625), (0.5, 0.5, 0.5))
    """Per-backbone normalisation means (DINOv2's are the bf16-rounded ImageNet means the processor stores)."""
    image_stds: tuple[tuple[float, float, float], ...] = (
        (0.228515625, 0.2236328125, 0.224609375),
        (0.5, 0.5, 0.5),
    )
    """Per-backbone normalisation stds."""
    timm_model_ids: tuple[str, str] = (
        "vit_large_patch14_reg4_dinov2.lvd142m",
        "vit_so400m_patch14_siglip_224",
    )
    """The official config's featurizer ids (kept for round trips)."""

    @property
    def vision_dim(self) -> int:
        return self.featurizer.embed_dim + self.fused_featurizer.embed_dim

    @property
    def num_patches(self) -> int:
        return self.featurizer.num_patches

    @property
    def action_vocab_end(self) -> int:
        """32000 for OpenVLA: token id t decodes to bin ``action_vocab_end - t - 1``."""
        return self.text.vocab_size - self.pad_to_multiple_of

    @property
    def num_hidden_states(self) -> int:
        return self.text.num_hidden_layers + 1

    def to_dict(self) -> JsonObject:
        """JSON-ready (tuples as lists); :meth:`from_dict` inverts it."""
        return json.loads(json.dumps(dataclasses.asdict(self)))

    @classmethod
    def from_dict(cls, d: JsonObject) -> OpenVLAConfig:
        d = dict(d)
        d["featurizer"] = ViTConfig(**d["featurizer"])
        d["fused_featurizer"] = ViTConfig(**d["fused_featurizer"])
        d["text"] = LlamaDims(**d["text"])
        d["image_means"] = tuple(tuple(m) for m in d["image_means"])
        d["image_stds"] = tuple(tuple(s) for s in d["image_stds"])
        d["timm_model_ids"] = tuple(d["timm_model_ids"])
        return cls(**d)


def openvla_7b() -> OpenVLAConfig:
    """The released OpenVLA-7B architecture (and its LIBERO fine-tunes)."""
    return OpenVLAConfig(
        featurizer=dataclasses.replace(TIMM_PRESETS["vit_large_patch14_reg4_dinov2.lvd142m"]),
        fused_featurizer=dataclasses.replace(TIMM_PRESETS["vit_so400m_patch14_siglip_224"]),
    )


_LLAMA_DEFAULTS = LlamaDims(
    hidden_size=4096,
    intermediate_size=11008,
    num_hidden_layers=32,
    num_attention_heads=32,
    num_key_value_heads=32,
)


def from_official(config: JsonObject, vision_overrides: dict[str, JsonObject] | None = None) -> OpenVLAConfig:
    """Build the architecture from an official OpenVLA ``config.json`` (already parsed).

    ``text_config`` lists only what differs from transformers' LlamaConfig defaults, so missing fields take
    those defaults. ``vision_overrides`` maps "featurizer"/"fused_featurizer" to ViTConfig fields that
    replace the timm preset (used for small test checkpoints with shrunk ViTs).
    """
    backbone = config.get("vision_backbone_id")
    if backbone != SUPPORTED_VISION_BACKBONE or not config.get("use_fused_vision_backbone", False):
        raise VlaprobeError(
            f"unsupported OpenVLA vision backbone {backbone!r}; vlaprobe implements {SUPPORTED_VISION_BACKBONE!r} "
            "(every released OpenVLA checkpoint)"
        )
    arch = config.get("arch_specifier", "")
    if not str(arch).endswith("fused-gelu-mlp"):
        raise VlaprobeError(f"unsupported OpenVLA projector {arch!r}; expected 'no-align+fused-gelu-mlp'")
    ids = tuple(config.get("timm_model_ids") or ())
    if ids != tuple(TIMM_PRESETS):
        raise VlaprobeError(f"unsupported timm_model_ids {list(ids)}; expected {list(TIMM_PRESETS)}")
    if any(config.get("timm_override_act_layers") or []):
        raise VlaprobeError("timm_override_act_layers must be [null, null] for dinosiglip; fix config.json")
    sizes = config.get("image_sizes", [224, 224])
    overrides = vision_overrides or {}
    vits = []
    for name, timm_id, size in zip(("featurizer", "fused_featurizer"), ids, sizes, strict=True):
        vit = dataclasses.replace(TIMM_PRESETS[timm_id], image_size=int(size))
        vits.append(dataclasses.replace(vit, **overrides.get(name, {})))
    tc = config.get("text_config") or {}
    llama_known = {f.name for f in dataclasses.fields(LlamaDims)}
    text = dataclasses.replace(_LLAMA_DEFAULTS, **{k: tc[k] for k in llama_known if k in tc})
    if "rope_parameters" in tc and isinstance(tc["rope_parameters"], dict):
        text.rope_theta = float(tc["rope_parameters"].get("rope_theta", text.rope_theta))
    if tc.get("model_type", "llama") != "llama":
        raise VlaprobeError(f"unsupported language model {tc.get('model_type')!r}; OpenVLA uses Llama-2")
    return OpenVLAConfig(
        featurizer=vits[0],
        fused_featurizer=vits[1],
        text=text,
        n_action_bins=int(config.get("n_action_bins", 256)),
        pad_to_multiple_of=int(config.get("pad_to_multiple_of", 64)),
        timm_model_ids=(ids[0], ids[1]),
    )


def to_official(cfg: OpenVLAConfig, norm_stats: JsonObject) -> JsonObject:
    """An official-format ``config.json`` for ``cfg`` (non-default Llama fields spelled out)."""
    text = dataclasses.asdict(cfg.text)
    return {
        "architectures": ["OpenVLAForActionPrediction"],
        "model_type": "openvla",
        "arch_specifier": "no-align+fused-gelu-mlp",
        "vision_backbone_id": SUPPORTED_VISION_BACKBONE,
        "llm_backbone_id": "llama2-7b-pure",
        "hf_llm_id": "meta-llama/Llama-2-7b-hf",
        "use_fused_vision_backbone": True,
        "image_resize_strategy": "resize-naive",
        "image_sizes": [cfg.featurizer.image_size, cfg.fused_featurizer.image_size],
        "timm_model_ids": list(cfg.timm_model_ids),
        "timm_override_act_layers": [None, None],
        "llm_max_length": cfg.text.max_position_embeddings,
        "n_action_bins": cfg.n_action_bins,
        "pad_to_multiple_of": cfg.pad_to_multiple_of,
        "pad_token_id": cfg.text.pad_token_id,
        "output_projector_states": False,
        "norm_stats": norm_stats,
        "text_config": {"model_type": "llama", **text},
    }
