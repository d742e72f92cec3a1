"""Small demonstration stores and a small-image OpenVLA checkpoint, so fine-tuning tests take seconds."""

from __future__ import annotations

from pathlib import Path

import numpy as np
from tests.collection.test_store import make_meta

from vlaprobe.collection.store import EpisodeInfo, episode_key
from vlaprobe.collection.writer import StoreWriter
from vlaprobe.policies.openvla import checkpoint
from vlaprobe.policies.openvla.config import LlamaDims, OpenVLAConfig, ViTConfig
from vlaprobe.policies.openvla.tiny import LIBERO_SPATIAL_LIKE_STATS, tiny_state_dict
from vlaprobe.policies.openvla.tokenizer import WordHashTokenizer

IMAGE = 28
"""Image side of the small model: 2×2 patches of 14 px, so a step costs a few milliseconds."""


def small_config(image_size: int = IMAGE, hidden_size: int = 32, layers: int = 2) -> OpenVLAConfig:
    """OpenVLA's structure at toy sizes: two small ViTs, the projector, a short Llama with the full vocabulary."""
    return OpenVLAConfig(
        featurizer=ViTConfig(
            embed_dim=32,
            depth=2,
            num_heads=2,
            mlp_hidden=64,
            class_token=True,
            reg_tokens=4,
            layer_scale=True,
            image_size=image_size,
        ),
        fused_featurizer=ViTConfig(
            embed_dim=32, depth=2, num_heads=2, mlp_hidden=64, map_head=True, image_size=image_size
        ),
        text=LlamaDims(
            hidden_size=hidden_size,
            intermediate_size=2 * hidden_size,
            num_hidden_layers=layers,
            num_attention_heads=2,
            num_key_value_heads=2,
        ),
    )


def write_small_model(folder: Path, image_size: int = IMAGE, hidden_size: int = 32, seed: int = 0) -> Path:
    """A vlaprobe checkpoint folder of :func:`small_config` with seeded weights."""
    import torch

    cfg = small_config(image_size, hidden_size)
    model = checkpoint.build_model(cfg, tiny_state_dict(cfg, seed), torch.device("cpu"), torch.float32)
    extra = {"tokenizer": WordHashTokenizer.name, "model_id": "small-test", "seed": seed}
    checkpoint.save_checkpoint(folder, model, LIBERO_SPATIAL_LIKE_STATS, extra)
    return folder


def demo_episode(task: int, init: int, length: int, image_size: int):
    """An episode whose action is a function of the image's brightness and the task (learnable)."""
    rng = np.random.default_rng([task, init])
    level = rng.integers(0, 4, length)  # 4 image classes, each with its own action
    base = rng.integers(0, 40, (length, image_size, image_size, 3))
    image = (base + 50 * level[:, None, None, None] + 20 * task).clip(0, 255).astype(np.uint8)
    action = np.zeros((length, 7), dtype=np.float32)
    action[:, 0] = 0.3 * (level - 1.5)
    action[:, 1] = 0.2 * (task - 1)
    action[:, 2] = rng.normal(0, 0.05, length)
    action[:, 6] = np.where(level >= 2, 1.0, -1.0)
    info = EpisodeInfo(episode_key(task, init), task, init, 0, True, length, seed=7, driver="expert")
    arrays = {
        "hidden": np.zeros((2, length, 4), dtype=np.float16),
        "object_atoms": np.zeros((length, 9), dtype=bool),
        "action_atoms": np.zeros((length, 2), dtype=bool),
        "image": image,
        "action": action,
        "proprio": rng.normal(0, 1, (length, 9)).astype(np.float32),
    }
    return info, arrays


def write_demo_store(
    path: Path, episodes: list[tuple[int, int, int]], image_size: int = IMAGE, images: bool = True
) -> Path:
    """A store of expert episodes (task, init, length) with images, actions and instructions."""
    meta = make_meta(num_hidden_states=2, hidden_size=4)
    with StoreWriter.open(path, meta) as w:
        for task, init, length in episodes:
            info, arrays = demo_episode(task, init, length, image_size)
            if not images:
                del arrays["image"]
            w.write_episode(info, arrays, {"instruction": f"put the bowl number {task} on the plate"})
    return path


def write_dagger_store(
    path: Path, episodes: list[tuple[int, int, int, bool]], image_size: int = IMAGE
) -> Path:
    """A ``--driver dagger`` store of episodes (task, init, length, success): the executed action is the
    model's (noise), the expert's label (``expert_action``) is the demonstration episode's action."""
    meta = make_meta(num_hidden_states=2, hidden_size=4, driver="dagger", dagger_beta=0.0)
    with StoreWriter.open(path, meta) as w:
        for task, init, length, success in episodes:
            info, arrays = demo_episode(task, init, length, image_size)
            info = EpisodeInfo(info.key, task, init, 0, success, length, seed=7, driver="dagger")
            arrays["expert_action"] = arrays["action"]
            arrays["action"] = np.random.default_rng(init).normal(0, 1, (length, 7)).astype(np.float32)
            w.write_episode(info, arrays, {"instruction": f"put the bowl number {task} on the plate"})
    return path
