"""``vlaprobe model-info`` and ``vlaprobe save-tiny``."""

from __future__ import annotations

import json
import time
from pathlib import Path

import numpy as np

from vlaprobe.configs.checks import check_policy, check_seed
from vlaprobe.configs.policy import ModelInfoConfig, SaveTinyConfig
from vlaprobe.errors import VlaprobeError
from vlaprobe.files import check_output_folder
from vlaprobe.policies.factory import make_policy


def model_info(cfg: ModelInfoConfig) -> int:
    """Print the policy's description (and optionally one timed step) as JSON."""
    check_policy(cfg.policy, "policy.")
    policy = make_policy(cfg.policy, cfg.suite)
    info = policy.describe()
    if cfg.step:
        y, x = np.mgrid[0:256, 0:256]
        frame = np.stack([x, y, (x + y) // 2], axis=-1).astype(np.uint8)
        start = time.perf_counter()
        step = policy.step(frame, cfg.instruction)
        info["step"] = {
            "seconds": round(time.perf_counter() - start, 4),
            "action": step.action.tolist(),
            "action_tokens": step.action_tokens.tolist(),
            "hidden_shape": list(step.hidden.shape),
        }
    print(json.dumps(info, indent=2))
    return 0


def save_tiny(cfg: SaveTinyConfig) -> int:
    """Write the tiny model for ``cfg.seed`` to ``cfg.out``."""
    from vlaprobe.policies.openvla.policy import OpenVLAPolicy

    check_seed(cfg.seed, "--seed")
    if cfg.patch_size < 1 or 224 % cfg.patch_size:
        raise VlaprobeError(
            f"--patch-size must divide the 224 px image (e.g. 14 or 28), got {cfg.patch_size}"
        )
    check_checkpoint_folder(cfg.out)
    OpenVLAPolicy.tiny(seed=cfg.seed, device="cpu", patch_size=cfg.patch_size).save_pretrained(cfg.out)
    print(f"wrote tiny OpenVLA (seed {cfg.seed}, patch {cfg.patch_size}) to {cfg.out}")
    return 0


CHECKPOINT_FILES = frozenset({"config.json", "model.safetensors"})
"""What ``save-tiny`` writes; a folder holding anything else is not overwritten."""


def check_checkpoint_folder(out: Path) -> None:
    """Refuse an ``out`` that holds more than a tiny checkpoint (a run, a store...), before writing."""
    check_output_folder(out)
    if out.is_dir():
        foreign = sorted(
            p.name for p in out.iterdir() if p.name not in CHECKPOINT_FILES and not p.name.startswith(".")
        )
        if foreign:
            raise VlaprobeError(
                f"--out {out} holds other files ({', '.join(foreign[:4])}); choose an empty or new folder"
            )
