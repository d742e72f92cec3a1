"""The lean KV-cached decoder against transformers' own cached decoding of the same Llama."""

from __future__ import annotations

import pytest
import torch
from transformers import LlamaConfig, LlamaForCausalLM

from vlaprobe.policies.openvla.decode import CachedDecoder

STEPS = 6


def _llama(dtype: torch.dtype, heads: int, kv_heads: int) -> LlamaForCausalLM:
    torch.manual_seed(0)
    cfg = LlamaConfig(
        vocab_size=300,
        hidden_size=64,
        intermediate_size=160,
        num_hidden_layers=4,
        num_attention_heads=heads,
        num_key_value_heads=kv_heads,
        rms_norm_eps=1e-6,
        attn_implementation="sdpa",
    )
    model = LlamaForCausalLM(cfg).eval()
    with torch.no_grad():  # transformers initialises norms to 1: perturb them so they matter
        for name, p in model.named_parameters():
            if "norm" in name:
                p.add_(0.2 * torch.randn_like(p))
    return model.to(dtype)


def _both(model: LlamaForCausalLM, record: bool) -> tuple[list, list]:
    """(ours, transformers'): per step, (logits (1, V), states (1, L+1, H) or None), fed the same tokens."""
    prompt = torch.randint(0, 300, (1, 40), generator=torch.Generator().manual_seed(1))
    with torch.inference_mode():
        out = model.model(input_ids=prompt, use_cache=True)
        decoder = CachedDecoder(model, out.past_key_values, prompt.shape[1], STEPS, record=record)
        ref_cache = out.past_key_values
        token = model.lm_head(out.last_hidden_state[:, -1]).argmax(-1)
        ours, theirs = [], []
        for _ in range(STEPS):
            ours.append(decoder.step(token))  # reads the cache before transformers appends to it below
            ref = model.model(
                input_ids=token[:, None], past_key_values=ref_cache, use_cache=True, output_hidden_states=True
            )
            ref_cache = ref.past_key_values
            states = torch.stack([h[:, -1] for h in ref.hidden_states], dim=1)
            theirs.append((model.lm_head(ref.last_hidden_state[:, -1]), states))
            token = theirs[-1][0].argmax(-1)
    return ours, theirs


@pytest.mark.parametrize(
    ("dtype", "heads", "kv_heads", "atol"),
    [
        (torch.float32, 2, 2, 1e-5),
        (torch.float32, 4, 2, 1e-5),  # grouped-query attention (not OpenVLA's, but Llama's)
        (torch.bfloat16, 2, 2, 0.0),  # OpenVLA's GPU dtype: transformers' own operation order, bit for bit
    ],
)
def test_matches_transformers_cached_decoding(dtype, heads, kv_heads, atol):
    model = _llama(dtype, heads, kv_heads)
    ours, theirs = _both(model, record=True)
    for (logits, states), (ref_logits, ref_states) in zip(ours, theirs, strict=True):
        assert logits.dtype == dtype and states.shape == (1, 5, 64)
        torch.testing.assert_close(logits, ref_logits, atol=atol, rtol=0 if atol == 0 else 1e-5)
        torch.testing.assert_close(states, ref_states, atol=atol, rtol=0 if atol == 0 else 1e-5)


def test_without_recording_returns_no_states():
    ours, theirs = _both(_llama(torch.float32, 2, 2), record=False)
    assert all(states is None for _, states in ours)
    torch.testing.assert_close(ours[-1][0], theirs[-1][0], atol=1e-5, rtol=1e-5)


def test_rejects_projection_biases():
    model = _llama(torch.float32, 2, 2)
    model.model.layers[0].self_attn.q_proj.bias = torch.nn.Parameter(torch.zeros(64))
    with torch.inference_mode():
        out = model.model(input_ids=torch.tensor([[1, 2, 3]]), use_cache=True)
        with pytest.raises(ValueError, match="biases"):
            CachedDecoder(model, out.past_key_values, 3, STEPS, record=False)


def test_a_batch_decodes_each_sequence_as_alone():
    """B prompts of one length decoded together give each prompt's own logits and states."""
    model = _llama(torch.float32, 4, 2)
    prompts = torch.randint(0, 300, (3, 40), generator=torch.Generator().manual_seed(2))
    with torch.inference_mode():

        def run(ids: torch.Tensor) -> list[tuple[torch.Tensor, torch.Tensor]]:
            out = model.model(input_ids=ids, use_cache=True)
            decoder = CachedDecoder(model, out.past_key_values, ids.shape[1], STEPS, record=True)
            token, steps = model.lm_head(out.last_hidden_state[:, -1]).argmax(-1), []
            for _ in range(STEPS):
                logits, states = decoder.step(token)
                steps.append((logits, states))
                token = logits.argmax(-1)
            return steps

        batch = run(prompts)
        for row in range(3):
            for (logits, states), (one_logits, one_states) in zip(
                batch, run(prompts[row : row + 1]), strict=True
            ):
                torch.testing.assert_close(logits[row : row + 1], one_logits, atol=1e-5, rtol=1e-5)
                torch.testing.assert_close(states[row : row + 1], one_states, atol=1e-5, rtol=1e-5)
    assert batch[0][1].shape == (3, 5, 64)
