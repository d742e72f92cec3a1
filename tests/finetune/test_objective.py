"""The objective's pieces on hand-made inputs: sequence layout, logits only where labelled, padding, pixels,
action binning, augmentation, episode split, schedule."""

from __future__ import annotations

import numpy as np
import pytest
import torch
from tests.finetune.helpers import small_config

from vlaprobe.configs.finetune import FinetuneConfig
from vlaprobe.finetune.augment import augment
from vlaprobe.finetune.data import Demonstrations, EpisodeRef, keep_rows, split_episodes
from vlaprobe.finetune.examples import majority_accuracy
from vlaprobe.finetune.loop import lr_at
from vlaprobe.finetune.objective import Batch, label_logits, pixel_batch, sequences
from vlaprobe.policies.openvla import checkpoint
from vlaprobe.policies.openvla.actions import decode_action, encode_action, normalize_action
from vlaprobe.policies.openvla.preprocessing import pixel_values
from vlaprobe.policies.openvla.tiny import tiny_state_dict


@pytest.fixture(scope="module")
def model():
    cfg = small_config()
    return checkpoint.build_model(cfg, tiny_state_dict(cfg, 3), torch.device("cpu"), torch.float32)


def test_labels_follow_the_sequence_layout() -> None:
    cfg = small_config()
    prompts = [[1, 50, 60, 29871], [1, 70, 29871]]
    tokens = np.array([[31744 + i for i in range(7)], [31990 - i for i in range(7)]])
    ids, positions, labels = sequences(prompts, tokens, cfg)
    assert ids.shape == (2, 4 + 7) and ids[1, -1] == cfg.text.pad_token_id  # right-padded
    assert labels[:, -1].tolist() == [cfg.text.eos_token_id] * 2
    p = cfg.num_patches
    for i in range(2):  # the state at positions[k] predicts the next token of the full sequence: label k
        full = [int(ids[i, 0])] + [-1] * p + ids[i, 1:].tolist()  # patches sit after <s>
        assert full[positions[i, 0]] == 29871
        for k in range(7):
            assert full[positions[i, k] + 1] == labels[i, k]


def test_label_logits_equal_the_policys_full_forward_and_ignore_padding(model) -> None:
    cfg = model.config
    rng = np.random.default_rng(0)
    images = rng.integers(0, 256, (2, 28, 28, 3), dtype=np.uint8)
    prompts = [[1, 50, 60, 70, 29871], [1, 80, 29871]]
    tokens = rng.integers(31744, 32000, (2, 7))
    pv = pixel_batch(images, cfg, torch.device("cpu"))
    ids, positions, labels = sequences(prompts, tokens, cfg)
    got = label_logits(model, Batch(pv, False, ids, positions, labels))
    for i in range(2):  # each alone, unpadded, through the inference path's uncached forward
        alone = torch.tensor([prompts[i] + tokens[i].tolist()])
        _, logits = model.forward(pv[i : i + 1], alone)
        torch.testing.assert_close(got[i], logits[0, positions[i]], atol=1e-5, rtol=1e-5)


def test_pixel_batch_is_the_policys_preprocessing_bit_for_bit() -> None:
    cfg = small_config()
    images = np.random.default_rng(1).integers(0, 256, (3, 28, 28, 3), dtype=np.uint8)
    batch = pixel_batch(images, cfg, torch.device("cpu")).numpy()
    for i in range(3):
        np.testing.assert_array_equal(batch[i], pixel_values(images[i], cfg.image_means, cfg.image_stds))


def test_binning_is_prismatics_action_tokenizer() -> None:
    q01, q99, mask = np.full(7, -0.5), np.full(7, 0.5), np.array([True] * 6 + [False])
    action = np.array([-0.5, 0.5, 0.0, 2.0, -2.0, 0.25, 1.0])
    normalized = normalize_action(action, q01, q99, mask)
    np.testing.assert_allclose(normalized, [-1, 1, 0, 1, -1, 0.5, 1.0], atol=1e-7)
    tokens = encode_action(normalized)
    assert tokens[0] == 31999 and tokens[6] == 31744  # digitize: -1 → bin 1, +1 → bin 256
    assert tokens[1] == 31745  # q99 normalises to 1 − 2e-8 (OpenVLA's +1e-8 in the denominator): bin 255
    assert encode_action(np.array([0.0, 0.004, -0.004])).tolist() == [31872, 31871, 31873]
    decoded = decode_action(tokens, q01, q99, mask)
    assert np.abs(decoded - np.clip(action, -0.5, 0.5))[:6].max() <= 1 / 255 + 1e-9
    every = np.linspace(-1, 1, 2001)[:, None].repeat(7, 1)  # encode then decode: within one bin everywhere
    assert (
        np.abs(decode_action(encode_action(every), -np.ones(7), np.ones(7), mask[:] | True) - every).max()
        <= 2 / 255
    )


def test_augmentation_is_seeded_and_stays_an_image() -> None:
    x = torch.rand(4, 3, 28, 28)
    a = augment(x, np.random.default_rng([0, 5]), 0.9)
    b = augment(x, np.random.default_rng([0, 5]), 0.9)
    c = augment(x, np.random.default_rng([0, 6]), 0.9)
    assert torch.equal(a, b) and not torch.equal(a, c)
    assert a.shape == x.shape and a.min() >= 0 and a.max() <= 1
    full = augment(
        x[:, :, :, :], np.random.default_rng(0), 1.0
    )  # crop of the whole image: only colour jitter
    assert full.shape == x.shape


def test_demonstration_rows_skip_terminal_post_success_and_idle_steps() -> None:
    actions = np.zeros((6, 7))
    actions[:, 6] = -1
    actions[1, 0] = actions[3, 0] = 0.5  # moves at rows 1 and 3
    actions[4, 6] = 1  # row 4 closes the gripper without moving: not idle
    actions[5] = np.nan  # terminal row
    assert keep_rows(actions, None, True, True).tolist() == [False, True, False, True, True, False]
    assert keep_rows(actions, 4, True, True).tolist() == [False, True, False, True, False, False]
    assert keep_rows(actions, 4, False, False).tolist() == [True] * 5 + [False]


def test_split_is_by_episode_and_per_task() -> None:
    episodes = [EpisodeRef(0, f"t{t}_i{i}", t, "x") for t in range(3) for i in range(5)]
    episode = np.repeat(np.arange(15), 4)
    demos = Demonstrations(np.zeros((60, 1, 1, 3), np.uint8), np.zeros((60, 7)), None, episode, episodes)
    split = split_episodes(demos, 0.2, seed=0)
    assert sorted(episodes[e].task for e in split.val_episodes) == [0, 1, 2]
    assert not set(split.train_episodes) & set(split.val_episodes)
    assert set(episode[split.val]) == set(split.val_episodes) and len(split.train) == 48
    assert split_episodes(demos, 0.2, seed=0).val_episodes == split.val_episodes
    assert split_episodes(demos, 0.2, seed=1).val_episodes != split.val_episodes
    thinned = split_episodes(demos, 0.2, seed=0, val_max_samples=5)
    assert len(thinned.val) == 5 and set(thinned.val) <= set(split.val)


def test_majority_baseline() -> None:
    tokens = np.array([[1, 2], [1, 3], [1, 3], [2, 3]])
    assert majority_accuracy(tokens, np.array([0, 1, 2]), np.array([3])) == 0.5


def test_warmup_then_cosine() -> None:
    cfg = FinetuneConfig(lr=1e-3, warmup_steps=10, min_lr_ratio=0.1)
    assert lr_at(0, 110, cfg) == pytest.approx(1e-4)
    assert lr_at(9, 110, cfg) == pytest.approx(1e-3)
    assert lr_at(60, 110, cfg) == pytest.approx(1e-3 * (0.1 + 0.9 * 0.5))
    assert lr_at(110, 110, cfg) == pytest.approx(1e-4)
