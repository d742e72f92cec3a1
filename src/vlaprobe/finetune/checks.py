"""Checks of ``vlaprobe finetune`` that run before any data is read or any step is taken: one line each."""

from __future__ import annotations

import dataclasses
import json
import math
from pathlib import Path

from vlaprobe.configs import config_to_dict
from vlaprobe.configs.checks import check_seed
from vlaprobe.configs.finetune import FinetuneConfig
from vlaprobe.errors import VlaprobeError
from vlaprobe.files import JsonObject, Setting, as_json, json_difference, settings_difference
from vlaprobe.finetune.state import CHECKPOINT, RUN_FILES, recover
from vlaprobe.policies.openvla.config import OpenVLAConfig

RUNTIME_FIELDS = frozenset({"out", "max_minutes", "threads", "progress", "device", "stores"})
"""Settings a resumed run may change (they do not change what is computed; stores are compared by their
statistics instead of their paths)."""
DEFINING = tuple(
    Setting(f.name, "--" + f.name.replace("_", "-"), config_to_dict(FinetuneConfig())[f.name])
    for f in dataclasses.fields(FinetuneConfig)
    if f.name not in RUNTIME_FIELDS
)
"""The settings that define a fine-tune run, the one list (a resume must share them): every setting but
:data:`RUNTIME_FIELDS`. One added after a run was written was at its default then."""


def _positive(value: float, flag: str, upper: float = math.inf) -> None:
    if not (math.isfinite(value) and 0 < value <= upper):
        bound = "" if upper == math.inf else f" and at most {upper:g}"
        raise VlaprobeError(f"{flag} must be a number above 0{bound}, got {value}")


def _at_least(value: int, low: int, flag: str) -> None:
    if value < low:
        raise VlaprobeError(f"{flag} must be at least {low}, got {value}")


def check_finetune(cfg: FinetuneConfig) -> None:
    """Ranges and combinations of the settings."""
    if not cfg.stores:
        raise VlaprobeError(
            "--stores needs at least one collection store, e.g. --stores runs/default/activations"
        )
    if not cfg.model:
        raise VlaprobeError("--model needs 'tiny' or an OpenVLA checkpoint folder, got ''")
    _positive(cfg.lr, "--lr", upper=1.0)
    _at_least(cfg.batch_size, 1, "--batch-size")
    _at_least(cfg.epochs, 1, "--epochs")
    if cfg.max_steps is not None:
        _at_least(cfg.max_steps, 1, "--max-steps")
    _at_least(cfg.warmup_steps, 0, "--warmup-steps")
    _at_least(cfg.eval_every, 0, "--eval-every")
    _at_least(cfg.val_max_samples, 0, "--val-max-samples")
    _at_least(cfg.lora_rank, 1, "--lora-rank")
    if not (0 < cfg.val_fraction < 1):
        raise VlaprobeError(f"--val-fraction must be between 0 and 1 (exclusive), got {cfg.val_fraction}")
    if not (math.isfinite(cfg.weight_decay) and cfg.weight_decay >= 0):
        raise VlaprobeError(f"--weight-decay must be 0 or a positive number, got {cfg.weight_decay}")
    if not (math.isfinite(cfg.grad_clip) and cfg.grad_clip >= 0):
        raise VlaprobeError(f"--grad-clip must be 0 (off) or a positive number, got {cfg.grad_clip}")
    if not (0 <= cfg.min_lr_ratio <= 1):
        raise VlaprobeError(f"--min-lr-ratio must be in [0, 1], got {cfg.min_lr_ratio}")
    if not (0 <= cfg.lora_dropout < 1):
        raise VlaprobeError(f"--lora-dropout must be in [0, 1), got {cfg.lora_dropout}")
    _positive(cfg.crop_scale, "--crop-scale", upper=1.0)
    if cfg.max_minutes is not None:
        _positive(cfg.max_minutes, "--max-minutes")
    if cfg.threads is not None:
        _at_least(cfg.threads, 1, "--threads")
    check_seed(cfg.seed, "--seed")
    check_seed(cfg.model_seed, "--model-seed")
    if cfg.augment and cfg.freeze_vision:
        raise VlaprobeError(
            "--augment needs the featurisers to see every augmented image, but --freeze-vision caches their "
            "features once; drop one of the two"
        )
    if cfg.lora and cfg.freeze_vision:
        raise VlaprobeError("--lora already freezes every base weight; drop --freeze-vision")


def check_run_folder(cfg: FinetuneConfig, arch: OpenVLAConfig) -> bool:
    """Whether ``--out`` holds a checkpoint to resume; refuses a folder of something else, a checkpoint of
    another model shape, or a run with other settings."""
    from vlaprobe.files import check_output_folder
    from vlaprobe.policies.openvla.checkpoint import read_config

    out = cfg.out
    check_output_folder(out)
    if not out.is_dir():
        return False
    recover(out)
    foreign = sorted(p.name for p in out.iterdir() if not p.name.startswith(".") and p.name not in RUN_FILES)
    if foreign:
        raise VlaprobeError(
            f"--out {out} holds other files ({', '.join(foreign[:4])}); choose a new folder for the fine-tune"
        )
    if not (out / CHECKPOINT).is_dir():
        return False
    saved_arch = read_config(out / CHECKPOINT)[0]
    shape = json_difference(as_json(saved_arch.to_dict()), as_json(arch.to_dict()))
    if shape:
        path, old, new = shape
        raise VlaprobeError(
            f"--out {out} holds a checkpoint of another model shape ({path[1:]} {old} vs {new}); "
            f"choose a new --out for --model {cfg.model}"
        )
    diff = settings_difference(DEFINING, _read_settings(out / "finetune.json"), config_to_dict(cfg), "folder")
    if diff:
        raise VlaprobeError(
            f"--out {out} holds a run with other settings ({diff}); rerun with its settings "
            f"(--config {out / 'finetune.json'}) to resume, or choose a new --out"
        )
    return True


def _read_settings(path: Path) -> JsonObject:
    try:
        data = json.loads(path.read_text())
    except (OSError, ValueError):
        raise VlaprobeError(
            f"{path} is missing or unreadable; delete {path.parent} or choose a new --out"
        ) from None
    return data if isinstance(data, dict) else {}
