"""Parity with the official OpenVLA code, on the reference vectors in ``shared/openvla_reference``.

Tolerances are the reference README's for an independent fp32 CPU implementation; measured here:
hidden states ≤ 2.3e-5, first logits ≤ 7.4e-6, patch features ≤ 2.4e-6, step logits ≤ 8.2e-6.
"""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import numpy as np
import pytest
import torch

from vlaprobe.policies.openvla import actions, checkpoint
from vlaprobe.policies.openvla.model import OpenVLA
from vlaprobe.policies.openvla.preprocessing import pixel_values

ATOL = 1e-4


@pytest.fixture(scope="module")
def ref_model(reference: Path) -> OpenVLA:
    cfg, _, _ = checkpoint.read_config(reference)
    cpu = torch.device("cpu")
    return checkpoint.build_model(
        cfg, checkpoint.read_state_dict(reference, cpu, torch.float32), cpu, torch.float32
    )


@pytest.fixture(scope="module")
def ref_stats(reference: Path) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    _, norm_stats, _ = checkpoint.read_config(reference)
    return actions.action_stats(norm_stats, "libero_spatial")


@pytest.mark.parametrize("i", [0, 1, 2])
def test_pixel_values_exact(cases, i):
    ours = pixel_values(cases[i]["image_uint8"].numpy())
    np.testing.assert_array_equal(ours, cases[i]["pixel_values"].numpy())


@pytest.mark.parametrize("i", [0, 1, 2])
def test_uncached_forward_matches(ref_model, cases, i):
    c = cases[i]
    pv, ids = c["pixel_values"][None], c["input_ids"][None]
    with torch.inference_mode():
        patches = ref_model.vision_backbone(pv)[0]
    torch.testing.assert_close(patches, c["patch_features"], atol=1e-5, rtol=0)
    hidden, logits = ref_model(pv, ids)
    assert len(hidden) == 33
    torch.testing.assert_close(torch.stack([h[0] for h in hidden]), c["hidden_states"], atol=ATOL, rtol=1e-5)
    torch.testing.assert_close(logits[0, -1], c["first_logits"], atol=ATOL, rtol=1e-5)


@pytest.mark.parametrize("i", [0, 1, 2])
def test_cached_decoding_matches(ref_model, ref_stats, cases, i):
    c = cases[i]
    pred = ref_model.predict(c["pixel_values"][None], c["input_ids"][None], pooling="action_tokens")
    assert pred.generated_ids.tolist() == c["action_token_ids"].tolist()
    assert pred.action_token_ids.tolist() == c["action_token_ids"].tolist()
    torch.testing.assert_close(
        pred.step_logits[:, 31744:32064], c["gen_step_logits_tail"], atol=ATOL, rtol=1e-5
    )
    # Row 0 of the captured states is the prompt pass itself: every layer at position T-1.
    torch.testing.assert_close(pred.hidden[:, 0], c["hidden_states"][:, -1], atol=ATOL, rtol=1e-5)
    # predict_action's output (before LIBERO's gripper post-processing), float64, bit for bit.
    got = actions.decode_action(pred.action_token_ids.numpy(), *ref_stats)
    np.testing.assert_array_equal(got, c["action"].numpy())


def test_pooled_states_come_from_the_same_pass(ref_model, cases):
    c = cases[2]
    ref = c["hidden_states"]
    n_text = c["input_ids"].shape[0]
    for pooling, expected in [
        ("last_prompt", ref[:, -1]),
        ("mean_all", ref.mean(1)),
        ("mean_text", torch.cat([ref[:, :1], ref[:, 257:]], 1).mean(1)),
    ]:
        pred = ref_model.predict(c["pixel_values"][None], c["input_ids"][None], pooling=pooling)
        assert pred.hidden.shape == (33, 16) and ref.shape[1] - 256 == n_text
        torch.testing.assert_close(pred.hidden, expected, atol=ATOL, rtol=1e-5)
        assert pred.generated_ids.tolist() == c["action_token_ids"].tolist()


def test_image_changes_the_action(cases):
    """openvla#346: OpenVLA's own code under transformers >= 4.50 silently drops the image in generate.
    Cases 0 and 1 share the prompt; only the image differs, and so must the tokens (checked above to be
    the official ones)."""
    assert torch.equal(cases[0]["input_ids"], cases[1]["input_ids"])
    assert cases[0]["action_token_ids"].tolist() != cases[1]["action_token_ids"].tolist()


def test_decode_table(reference, ref_stats):
    table = json.loads((reference / "cases.json").read_text())["decode_table"]
    for row in table:
        ids = np.array(row["token_ids"])
        np.testing.assert_array_equal(np.clip(32000 - ids - 1, 0, 254), row["bin_index"])
        np.testing.assert_allclose(
            actions.bin_centers()[row["bin_index"]], row["normalized"], rtol=0, atol=1e-15
        )
        np.testing.assert_allclose(actions.decode_action(ids, *ref_stats), row["action"], rtol=0, atol=1e-15)


def _llama_like_tokenizer(folder: Path, pieces: dict[str, int]) -> None:
    """A Unigram tokenizer.json with Llama-2's normaliser that maps the reference prompts to the
    reference ids (the real Llama vocabulary is not available offline)."""
    from tokenizers import Tokenizer, normalizers
    from tokenizers.models import Unigram

    vocab = [(f"<filler{i}>", -100.0) for i in range(32000)]
    vocab[0], vocab[1], vocab[2] = ("<unk>", 0.0), ("<s>", 0.0), ("</s>", 0.0)
    for piece, i in pieces.items():
        vocab[i] = (piece, -1.0)
    tok = Tokenizer(Unigram(vocab, unk_id=0))
    tok.normalizer = normalizers.Sequence([normalizers.Prepend("▁"), normalizers.Replace(" ", "▁")])
    tok.save(str(folder / "tokenizer.json"))
    (folder / "tokenizer_config.json").write_text(json.dumps({"bos_token": "<s>", "add_bos_token": True}))


PIECES = {
    "▁In": 512, ":": 29901, "▁What": 1724, "▁action": 3158, "▁should": 881, "▁the": 278, "▁robot": 19964,
    "▁take": 2125, "▁to": 304, "▁pick": 5839, "▁up": 701, "▁black": 4628, "▁bow": 12580, "l": 29880,
    "▁between": 1546, "▁plate": 15284, "▁and": 322, "▁r": 364, "am": 420, "ekin": 9089, "▁place": 2058,
    "▁it": 372, "▁on": 373, "?": 29973, "\n": 13, "Out": 3744, "▁put": 1925, "▁both": 1716,
    "▁alphabet": 22968, "▁soup": 22300, "▁tom": 6454, "ato": 1219, "▁sau": 12507, "ce": 346, "▁in": 297,
    "▁basket": 25972,
}  # fmt: skip


def test_end_to_end_from_raw_libero_frame(reference, cases, tmp_path):
    """Raw agentview frame + instruction → LIBERO preprocessing → tokenizer.json → model → action, through
    ``make_policy`` on an official-layout folder, equals the official pipeline's case 0."""
    from vlaprobe.configs.policy import PolicyConfig
    from vlaprobe.policies import make_policy

    for name in ("config.json", "model.safetensors", "tiny_dims.json"):
        shutil.copy(reference / name, tmp_path / name)
    _llama_like_tokenizer(tmp_path, PIECES)
    policy = make_policy(PolicyConfig(str(tmp_path), pooling="last_prompt", device="cpu"))
    assert policy.prompt_ids("Put both the alphabet soup and the tomato sauce in the basket")[0].tolist() == (
        cases[2]["input_ids"].tolist()
    )
    raw = np.load(reference / "preprocess_cases.npz")["input_256"][0]
    step = policy.step(
        raw, "pick up the black bowl between the plate and the ramekin and place it on the plate"
    )
    np.testing.assert_array_equal(step.model_image, cases[0]["image_uint8"].numpy())
    assert step.action_tokens.tolist() == cases[0]["action_token_ids"].tolist()
    np.testing.assert_array_equal(step.action, actions.libero_gripper(cases[0]["action"].numpy()))
    np.testing.assert_allclose(step.hidden, cases[0]["hidden_states"][:, -1].numpy(), atol=ATOL, rtol=1e-5)
    assert step.action[-1] == -1.0  # gripper 0.97 in the data's convention (1 = open) → -1 = open for LIBERO
