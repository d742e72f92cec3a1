"""The tiny OpenVLA behind the policy interface: shapes, single-pass capture, determinism, save/load."""

from __future__ import annotations

import json

import numpy as np
import pytest
import torch

from vlaprobe.configs.policy import PolicyConfig
from vlaprobe.policies import POOLINGS, PolicyStep, VLAPolicy, make_policy
from vlaprobe.policies.openvla.policy import OpenVLAPolicy
from vlaprobe.policies.openvla.tiny import TINY_HIDDEN_SIZE, tiny_config, tiny_state_dict

INSTRUCTION = "pick up the black bowl between the plate and the ramekin and place it on the plate"


def _frames() -> list[np.ndarray]:
    """Four unlike frames: a colour gradient, uniform noise, mid grey, near black."""
    y, x = np.mgrid[0:256, 0:256]
    return [
        np.stack([x, y, (x + y) // 2], axis=-1).astype(np.uint8),
        np.random.default_rng(0).integers(0, 256, (256, 256, 3), dtype=np.uint8),
        np.full((256, 256, 3), 128, dtype=np.uint8),
        np.full((256, 256, 3), 30, dtype=np.uint8),
    ]


def _with_pooling(policy: OpenVLAPolicy, pooling: str) -> OpenVLAPolicy:
    return OpenVLAPolicy(
        policy.model,
        policy.tokenizer,
        policy.norm_stats,
        model_id=policy.model_id,
        pooling=pooling,  # type: ignore[arg-type]
    )


@pytest.mark.parametrize("pooling", POOLINGS)
def test_step_shapes(tiny, pooling):
    policy = _with_pooling(tiny, pooling)
    assert isinstance(policy, VLAPolicy)
    assert policy.num_hidden_states == 33 and policy.hidden_size == TINY_HIDDEN_SIZE
    step = policy.step(_frames()[0], INSTRUCTION)
    assert isinstance(step, PolicyStep)
    expected = (33, 7, TINY_HIDDEN_SIZE) if pooling == "action_tokens" else (33, TINY_HIDDEN_SIZE)
    assert step.hidden.shape == expected and step.hidden.dtype == np.float32
    assert np.isfinite(step.hidden).all()
    assert step.action.shape == (7,) and step.action.dtype == np.float64
    assert step.action[-1] in (-1.0, 0.0, 1.0)
    assert step.action_tokens.shape == (7,) and step.action_tokens.dtype == np.int64
    assert step.model_image.shape == (224, 224, 3) and step.model_image.dtype == np.uint8


def test_captured_states_equal_a_separate_uncached_pass(tiny):
    """The capture comes from the prompt pass and the cached decode steps, yet equals one uncached forward
    over prompt + fed-back action tokens, position by position."""
    frame = _frames()[1]
    image = tiny.model_image(frame)
    ids = tiny.prompt_ids(INSTRUCTION)
    pv = tiny.pixel_values(image)
    t = ids.shape[1] + 256
    pred = tiny.predict(image, ids, "action_tokens")
    full = torch.cat([ids, pred.generated_ids[None, :6]], dim=1)
    hidden, logits = tiny.model(pv, full)
    ref = torch.stack([h[0] for h in hidden])  # (33, T + 6, H)
    torch.testing.assert_close(pred.hidden, ref[:, t - 1 : t + 6], atol=1e-4, rtol=1e-5)
    assert logits[0, t - 1 :].argmax(-1).tolist() == pred.generated_ids.tolist()
    prompt_ref = ref[:, :t]
    expected = {
        "last_prompt": prompt_ref[:, -1],
        "mean_all": prompt_ref.mean(1),
        "mean_text": torch.cat([prompt_ref[:, :1], prompt_ref[:, 257:]], 1).mean(1),
    }
    for pooling, want in expected.items():
        got = torch.from_numpy(_with_pooling(tiny, pooling).step(frame, INSTRUCTION).hidden)
        torch.testing.assert_close(got, want, atol=1e-4, rtol=1e-5)


def test_images_change_states_and_actions(tiny):
    """openvla#346 was a model that ignored its image: here every frame yields its own states and action."""
    steps = [tiny.step(frame, INSTRUCTION) for frame in _frames()]
    for a in range(len(steps)):
        for b in range(a + 1, len(steps)):
            assert not np.allclose(steps[a].hidden, steps[b].hidden, atol=1e-3)
            assert steps[a].action_tokens.tolist() != steps[b].action_tokens.tolist()
            assert not np.array_equal(steps[a].action, steps[b].action)
    again = tiny.step(_frames()[0], INSTRUCTION)
    np.testing.assert_array_equal(again.hidden, steps[0].hidden)
    np.testing.assert_array_equal(again.action, steps[0].action)


def test_instruction_changes_the_states(tiny):
    a = tiny.step(_frames()[0], INSTRUCTION).hidden
    b = tiny.step(_frames()[0], "open the top drawer of the cabinet").hidden
    np.testing.assert_array_equal(a[0], b[0])  # layer 0 at "▁" (29871) is the same token embedding
    assert not np.allclose(a[1:], b[1:], atol=1e-4)


def test_seeded_weights():
    cfg = tiny_config()
    a, b, c = tiny_state_dict(cfg, 0), tiny_state_dict(cfg, 0), tiny_state_dict(cfg, 1)
    assert all(torch.equal(a[k], b[k]) for k in a)
    assert not torch.equal(a["projector.fc1.weight"], c["projector.fc1.weight"])


def test_save_load_round_trip_is_exact(tiny, tmp_path):
    tiny.save_pretrained(tmp_path / "ckpt")
    assert sorted(p.name for p in (tmp_path / "ckpt").iterdir()) == ["config.json", "model.safetensors"]
    loaded = make_policy(PolicyConfig(str(tmp_path / "ckpt"), pooling="action_tokens", device="cpu"))
    assert loaded.model_id == tiny.model_id
    ours, theirs = tiny.model.state_dict(), loaded.model.state_dict()
    assert ours.keys() == theirs.keys() and all(torch.equal(ours[k], theirs[k]) for k in ours)
    frame = _frames()[2]
    want, got = _with_pooling(tiny, "action_tokens").step(frame, INSTRUCTION), loaded.step(frame, INSTRUCTION)
    np.testing.assert_array_equal(got.hidden, want.hidden)
    np.testing.assert_array_equal(got.action, want.action)
    np.testing.assert_array_equal(got.action_tokens, want.action_tokens)


def test_describe_is_json_metadata(tiny):
    info = tiny.describe()
    assert json.loads(json.dumps(info)) == info
    assert info["model_id"] == "tiny-openvla-seed0" and info["seed"] == 0
    assert info["num_hidden_states"] == 33 and info["hidden_size"] == TINY_HIDDEN_SIZE
    assert info["dtype"] == "float32" and info["device"] == "cpu" and info["pooling"] == "last_prompt"
    assert info["architecture"]["text"]["num_hidden_layers"] == 32
    assert info["unnorm_key"] == "libero_spatial"
