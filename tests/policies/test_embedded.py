"""The shipped trained observer `tiny-libero`: it loads by name, has the declared shape and statistics, and
acts. (The training itself is `vlaprobe finetune` with recipes/tiny-libero.yaml; tests never re-train it.)"""

from __future__ import annotations

import numpy as np

from vlaprobe.configs.policy import PolicyConfig
from vlaprobe.configs.serve import ServeConfig
from vlaprobe.policies import make_policy
from vlaprobe.policies.openvla.embedded import DEFAULT_MODEL, embedded_folder
from vlaprobe.policies.openvla.tokenizer import ACTION_ID_RANGE


def test_the_default_observer_is_the_shipped_model() -> None:
    assert PolicyConfig().model == ServeConfig().model == DEFAULT_MODEL == "tiny-libero"
    folder = embedded_folder(DEFAULT_MODEL)
    assert folder is not None and embedded_folder("tiny") is None
    weights = folder / "model.safetensors"
    assert weights.is_file() and weights.stat().st_size <= 25 * 2**20  # the size limit


def test_shipped_weights_load_with_the_declared_shape_and_statistics() -> None:
    policy = make_policy(PolicyConfig("tiny-libero", device="cpu"))
    cfg = policy.model.config
    assert policy.model_id == "tiny-libero"
    assert (policy.num_hidden_states, policy.hidden_size) == (33, 64)  # OpenVLA's 33 states
    assert cfg.num_patches == 64 and cfg.featurizer.patch_size == cfg.fused_featurizer.patch_size == 28
    assert cfg.text.vocab_size == 32064 and cfg.action_vocab_end == 32000
    stats = policy.norm_stats["libero_spatial"]["action"]
    q01, q99 = np.array(stats["q01"]), np.array(stats["q99"])
    assert stats["mask"] == [True] * 6 + [False] and np.all(q01[:6] < q99[:6])
    assert all(p.dtype == policy.dtype for p in policy.model.parameters())  # float16 on disk, fp32 here
    random = make_policy(PolicyConfig("tiny", device="cpu"))
    assert random.model_id == "tiny-openvla-seed0" and random.model.config.num_patches == 256
    init = make_policy(
        PolicyConfig("tiny-libero-init", device="cpu")
    )  # the control: the same network before training
    assert init.model.config == cfg and init.model_id == "tiny-openvla-p28-seed0"


def test_shipped_model_produces_valid_actions() -> None:
    policy = make_policy(PolicyConfig("tiny-libero", device="cpu"))
    rng = np.random.default_rng(0)
    for _ in range(2):
        frame = rng.integers(0, 255, (256, 256, 3), dtype=np.uint8)
        step = policy.step(frame, "pick up the black bowl on the ramekin and place it on the plate")
        assert step.action.shape == (7,) and np.all(np.isfinite(step.action))
        assert step.action[6] in (-1.0, 1.0)
        assert np.all(
            np.abs(step.action[:6]) <= np.maximum(np.abs(policy._q01), np.abs(policy._q99))[:6] + 1e-9
        )
        assert np.all((step.action_tokens >= ACTION_ID_RANGE[0]) & (step.action_tokens < ACTION_ID_RANGE[1]))
        assert step.hidden.shape == (33, 64) and np.all(np.isfinite(step.hidden))


def test_every_shipped_model_loads_by_name_within_the_size_limit() -> None:
    from vlaprobe.policies.openvla.embedded import EMBEDDED_MODELS

    assert "tiny-libero-diverse" in EMBEDDED_MODELS  # issue 38's observer (recipes/tiny-libero-diverse.yaml)
    for name in EMBEDDED_MODELS:
        folder = embedded_folder(name)
        assert folder is not None and (folder / "model.safetensors").stat().st_size <= 25 * 2**20
        policy = make_policy(PolicyConfig(name, device="cpu"))
        assert policy.model_id == name and (policy.num_hidden_states, policy.hidden_size) == (33, 64)
        step = policy.step(
            np.zeros((256, 256, 3), np.uint8), "pick up the black bowl and place it on the plate"
        )
        assert np.all(np.isfinite(step.action)) and np.all(np.isfinite(step.hidden))
