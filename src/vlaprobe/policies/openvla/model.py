"""The OpenVLA network and its single-pass, KV-cached greedy action decoding with hidden-state capture.

Sequence layout (as OpenVLA's ``PrismaticForConditionalGeneration.forward`` builds it)::

    position  0        1 … P          P+1 … T−1                          T … T+5
              <s>      P patch tokens  prompt tokens 1 … L−1 (last: 29871)  action tokens 0 … 5 (fed back)

with P = 256 and T = L + P. Rotary positions run 0 … T−1 over the whole sequence, patches included. The
state at position T−1 predicts action token 0; action token k, fed at position T+k, predicts token k+1.
The prompt goes through the decoder once: that pass yields every layer's hidden states *and* the logits
of the first action token; the other six tokens are decoded one position at a time with the KV cache
(``decode.CachedDecoder``).
"""

from __future__ import annotations

from dataclasses import dataclass

import torch
from torch import nn
from transformers import LlamaConfig, LlamaForCausalLM

from vlaprobe.policies.base import Pooling
from vlaprobe.policies.openvla.config import OpenVLAConfig
from vlaprobe.policies.openvla.decode import CachedDecoder
from vlaprobe.policies.openvla.vision import FusedVisionBackbone, Projector

ACTION_DIM = 7
"""Tokens per action: x, y, z, roll, pitch, yaw, gripper."""


def llama_config(cfg: OpenVLAConfig) -> LlamaConfig:
    """transformers' LlamaConfig for the decoder (SDPA attention, untied embeddings)."""
    t = cfg.text
    return LlamaConfig(  # type: ignore[call-arg]  # rope_theta, attn_implementation: **kwargs on transformers 5
        vocab_size=t.vocab_size,
        hidden_size=t.hidden_size,
        intermediate_size=t.intermediate_size,
        num_hidden_layers=t.num_hidden_layers,
        num_attention_heads=t.num_attention_heads,
        num_key_value_heads=t.num_key_value_heads,
        rms_norm_eps=t.rms_norm_eps,
        rope_theta=t.rope_theta,
        max_position_embeddings=t.max_position_embeddings,
        pad_token_id=t.pad_token_id,
        bos_token_id=t.bos_token_id,
        eos_token_id=t.eos_token_id,
        tie_word_embeddings=False,
        attn_implementation="sdpa",
    )


@dataclass
class Prediction:
    """What one step of work yields (tensors stay on the model's device and dtype)."""

    action_token_ids: torch.Tensor
    """(7,) int64: the ids OpenVLA's ``predict_action`` decodes (the last 7 of prompt + generated)."""
    generated_ids: torch.Tensor
    """(7,) int64: the greedy token chosen at each of the 7 steps."""
    step_logits: torch.Tensor
    """(7, vocab) logits that chose each generated token (row 0: the prompt pass)."""
    hidden: torch.Tensor | None
    """Pooled hidden states: (L, H), or (L, 7, H) for "action_tokens"; None without capture."""


class OpenVLA(nn.Module):
    """Vision backbone + projector + Llama, named like the official ``OpenVLAForActionPrediction``."""

    def __init__(self, config: OpenVLAConfig) -> None:
        super().__init__()
        self.config = config
        self.vision_backbone = FusedVisionBackbone(config.featurizer, config.fused_featurizer)
        self.projector = Projector(config.vision_dim, config.text.hidden_size)
        self.language_model = LlamaForCausalLM(llama_config(config))

    def embed(self, pixel_values: torch.Tensor, input_ids: torch.Tensor) -> torch.Tensor:
        """(B, 6, 224, 224), (B, L) → (B, L + P, H): [embed(<s>), projector(patches), embed(rest)]."""
        return self.embed_features(
            self.vision_backbone(pixel_values.to(self.projector.fc1.weight.dtype)), input_ids
        )

    def embed_features(self, features: torch.Tensor, input_ids: torch.Tensor) -> torch.Tensor:
        """:meth:`embed` from the fused backbone's patch features (B, P, V), e.g. cached ones."""
        patches = self.projector(features.to(self.projector.fc1.weight.dtype))
        tokens = self.language_model.get_input_embeddings()(input_ids)
        return torch.cat([tokens[:, :1], patches, tokens[:, 1:]], dim=1)

    @torch.inference_mode()
    def forward(
        self, pixel_values: torch.Tensor, input_ids: torch.Tensor
    ) -> tuple[tuple[torch.Tensor, ...], torch.Tensor]:
        """One uncached pass over the whole sequence: (all hidden states, each (1, T, H)), logits (1, T, V).

        The reference the cached decoder is checked against; ``input_ids`` may include action tokens.
        """
        out = self.language_model.model(
            inputs_embeds=self.embed(pixel_values, input_ids), use_cache=False, output_hidden_states=True
        )
        return out.hidden_states, self.language_model.lm_head(out.last_hidden_state)

    @torch.inference_mode()
    def predict(
        self, pixel_values: torch.Tensor, input_ids: torch.Tensor, pooling: Pooling | None = None
    ) -> Prediction:
        """Greedy-decode 7 action tokens; with ``pooling``, capture every layer's states from the same passes.

        ``input_ids`` (1, L) must start with <s> and end with the empty token 29871.
        """
        return self.predict_batch(pixel_values, input_ids, pooling)[0]

    @torch.inference_mode()
    def predict_batch(
        self, pixel_values: torch.Tensor, input_ids: torch.Tensor, pooling: Pooling | None = None
    ) -> list[Prediction]:
        """:meth:`predict` for B images (B, 6, 224, 224) under one prompt ``input_ids`` (1, L), in one prompt
        pass and one batched decode; B = 1 runs exactly the operations of a single prediction."""
        lm, b = self.language_model, pixel_values.shape[0]
        capture = pooling is not None
        out = lm.model(
            inputs_embeds=self.embed(pixel_values, input_ids.expand(b, -1)),
            use_cache=True,
            output_hidden_states=capture,
        )
        hidden = None
        if pooling is not None:
            states, n = out.hidden_states, self.config.num_patches
            hidden = torch.stack([_pool(tuple(h[i : i + 1] for h in states), pooling, n) for i in range(b)])
        per_step: list[torch.Tensor] | None = (
            [hidden] if hidden is not None and pooling == "action_tokens" else None
        )
        logits = [lm.lm_head(out.last_hidden_state[:, -1])]
        tokens = [logits[-1].argmax(-1)]
        cache = out.get("cache")  # transformers 5.2x renamed past_key_values (and warns on the old name)
        if cache is None:
            cache = out.past_key_values
        decoder = CachedDecoder(
            lm, cache, out.last_hidden_state.shape[1], ACTION_DIM - 1, record=per_step is not None
        )
        for _ in range(ACTION_DIM - 1):
            step_logits, step_states = decoder.step(tokens[-1])
            if per_step is not None:
                assert step_states is not None  # the decoder records when per_step is kept
                per_step.append(step_states)
            logits.append(step_logits)
            tokens.append(step_logits.argmax(-1))
        generated = torch.stack(tokens, dim=1)  # (B, 7)
        if per_step is not None:
            hidden = torch.stack(per_step, dim=2)  # (B, L, 7, H)
        step_logits = torch.stack(logits, dim=1)  # (B, 7, V)
        eos = self.config.text.eos_token_id
        return [
            Prediction(
                action_token_ids=_official_action_ids(input_ids[0], generated[i], eos),
                generated_ids=generated[i],
                step_logits=step_logits[i],
                hidden=hidden[i] if hidden is not None else None,
            )
            for i in range(b)
        ]


def _pool(hidden_states: tuple[torch.Tensor, ...], pooling: Pooling, num_patches: int) -> torch.Tensor:
    """Reduce each (1, T, H) layer state to (H,) without stacking the full (L, T, H) tensor first."""
    if pooling in ("last_prompt", "action_tokens"):
        return torch.stack([h[0, -1] for h in hidden_states])
    f32 = torch.float32  # means accumulate in float32 also when the model runs in bf16
    if pooling == "mean_all":
        return torch.stack([h[0].mean(0, dtype=f32) for h in hidden_states])
    if pooling == "mean_text":  # <s> at 0 and the prompt tokens after the patches
        n = hidden_states[0].shape[1] - num_patches
        return torch.stack(
            [(h[0, 0].to(f32) + h[0, num_patches + 1 :].sum(0, dtype=f32)) / n for h in hidden_states]
        )
    raise ValueError(f"unknown pooling {pooling!r}")


def _official_action_ids(prompt: torch.Tensor, generated: torch.Tensor, eos: int) -> torch.Tensor:
    """The ids ``predict_action`` decodes: transformers' ``generate`` stops after an eos token, and
    OpenVLA then takes the last 7 ids of prompt + generated, reaching back into the prompt."""
    stop = (generated == eos).nonzero()
    if len(stop) == 0:
        return generated
    return torch.cat([prompt, generated[: int(stop[0]) + 1]])[-ACTION_DIM:]
