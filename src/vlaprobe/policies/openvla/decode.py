"""The six KV-cached decode steps after the prompt pass, in plain torch over the Llama's own weights.

Each step feeds one action token through the 32 decoder layers. For a small model most of such a step is
per-operation overhead, and transformers' ``LlamaModel.forward`` adds its own per layer (module dispatch,
mask and cache bookkeeping, a cache that grows by concatenation, ``rotate_half`` by slicing and
concatenating). This loop computes the same thing in transformers' operation order (RMSNorm in float32 then
cast, rotary embedding in the model's dtype, SDPA with the 1/√d scale, SiLU-gated MLP) on the weights of the
``LlamaForCausalLM`` the checkpoint was loaded into, writing keys and values into buffers preallocated for
the whole decode and seeded from the prompt pass's cache. ``bench/tiny_forward.py`` measures it against
transformers' decoding; ``tests/policies/test_decode.py`` holds it to transformers' cached decoding
(bit for bit in bfloat16) and the policy tests to an uncached pass over the same tokens.
"""

from __future__ import annotations

from typing import Any

import torch
import torch.nn.functional as F
from transformers import LlamaForCausalLM


def _rms_norm(x: torch.Tensor, weight: torch.Tensor, eps: float) -> torch.Tensor:
    """``LlamaRMSNorm``: normalise in float32, cast back, then scale (one fused op for float32 input)."""
    if x.dtype == torch.float32:
        return F.rms_norm(x, weight.shape, weight, eps)
    xf = x.float()
    xf = xf * torch.rsqrt(xf.pow(2).mean(-1, keepdim=True) + eps)
    return weight * xf.to(x.dtype)


def _rotate_half_matrix(d: int, like: torch.Tensor) -> torch.Tensor:
    """The signed permutation R with ``x @ R == rotate_half(x) == cat(-x[d/2:], x[:d/2])``, exactly: each
    output is one input times ±1, so one small matmul replaces transformers' slice-negate-concatenate."""
    r = torch.zeros(d, d, dtype=like.dtype, device=like.device)
    half = d // 2
    idx = torch.arange(half, device=like.device)
    r[idx + half, idx] = -1
    r[idx, idx + half] = 1
    return r


def _cache_layer(cache: Any, i: int) -> tuple[torch.Tensor, torch.Tensor]:
    """Layer ``i``'s (keys, values), each (B, kv_heads, T, d), from a transformers ``DynamicCache``."""
    layers = getattr(cache, "layers", None)
    if layers is not None:  # transformers >= 4.56
        return layers[i].keys, layers[i].values
    return cache.key_cache[i], cache.value_cache[i]


def _layer_weights(layer: Any) -> tuple[Any, ...]:
    """One ``LlamaDecoderLayer``'s tensors, read once (module attribute lookups cost as much as tiny ops)."""
    attn, mlp = layer.self_attn, layer.mlp
    linears = (attn.q_proj, attn.k_proj, attn.v_proj, attn.o_proj, mlp.gate_proj, mlp.up_proj, mlp.down_proj)
    if any(lin.bias is not None for lin in linears):
        raise ValueError("OpenVLA's Llama has no projection biases")
    n1, n2 = layer.input_layernorm, layer.post_attention_layernorm
    return (
        n1.weight,
        n1.variance_epsilon,
        *(lin.weight for lin in linears[:4]),
        n2.weight,
        n2.variance_epsilon,
        *(lin.weight for lin in linears[4:]),
        mlp.act_fn,
    )


class CachedDecoder:
    """Greedy single-token steps continuing a prompt pass: ``step(tokens)`` → (logits (B, V), states or None).

    ``states`` (when ``record``) is every layer's state at the fed position, (B, L + 1, H), in transformers'
    ``output_hidden_states`` convention: the embedding, each layer's output, the last one after the final norm.
    A batch of B sequences shares one prompt length (the prompt pass ran on B images with the same prompt).
    """

    def __init__(
        self, lm: LlamaForCausalLM, cache: Any, prompt_length: int, steps: int, record: bool
    ) -> None:
        model = lm.model
        self.lm = lm
        self.weights = [_layer_weights(layer) for layer in model.layers]
        self.record = record
        self.start = self.position = prompt_length
        attn = model.layers[0].self_attn
        self.head_dim = attn.head_dim
        self.scale = attn.scaling
        self.gqa = attn.num_key_value_groups > 1
        self.keys: list[torch.Tensor] = []
        self.values: list[torch.Tensor] = []
        for i in range(len(self.weights)):
            k, v = _cache_layer(cache, i)
            buf_k = k.new_empty(k.shape[0], k.shape[1], prompt_length + steps, k.shape[3])
            buf_v = torch.empty_like(buf_k)
            buf_k[:, :, :prompt_length] = k[:, :, :prompt_length]
            buf_v[:, :, :prompt_length] = v[:, :, :prompt_length]
            self.keys.append(buf_k)
            self.values.append(buf_v)
        embed = model.embed_tokens.weight
        positions = torch.arange(prompt_length, prompt_length + steps, device=embed.device)[None]
        cos, sin = model.rotary_emb(embed[:1], positions)  # (1, steps, d) each, in the model's dtype
        self.cos, self.sin = cos[0], sin[0]
        self.rotate_half = _rotate_half_matrix(self.head_dim, embed)

    def step(self, tokens: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor | None]:
        """Feed ``tokens`` (shape (B,), one per sequence) at the next position."""
        model = self.lm.model
        p, b = self.position, tokens.shape[0]
        cos, sin = self.cos[p - self.start], self.sin[p - self.start]
        x = model.embed_tokens(tokens)[:, None]  # (B, 1, H)
        states = [x[:, 0]] if self.record else None
        d, r = self.head_dim, self.rotate_half
        last = len(self.weights) - 1
        for i, (n1, eps1, wq, wk, wv, wo, n2, eps2, wg, wu, wd, act) in enumerate(self.weights):
            h = _rms_norm(x, n1, eps1)
            q = F.linear(h, wq).view(b, 1, -1, d).transpose(1, 2)
            q = q * cos + (q @ r) * sin
            k = F.linear(h, wk).view(b, 1, -1, d).transpose(1, 2)
            torch.add(k * cos, (k @ r) * sin, out=self.keys[i][:, :, p : p + 1])
            self.values[i][:, :, p : p + 1] = F.linear(h, wv).view(b, 1, -1, d).transpose(1, 2)
            a = F.scaled_dot_product_attention(
                q,
                self.keys[i][:, :, : p + 1],
                self.values[i][:, :, : p + 1],
                scale=self.scale,
                enable_gqa=self.gqa,
            )
            x = x + F.linear(a.transpose(1, 2).reshape(b, 1, -1), wo)
            h = _rms_norm(x, n2, eps2)
            x = x + F.linear(act(F.linear(h, wg)) * F.linear(h, wu), wd)
            if states is not None and i < last:
                states.append(x[:, 0])
        x = _rms_norm(x, model.norm.weight, model.norm.variance_epsilon)
        self.position += 1
        if states is not None:
            states.append(x[:, 0])
        return self.lm.lm_head(x[:, -1]), (torch.stack(states, dim=1) if states is not None else None)
