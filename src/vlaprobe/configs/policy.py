"""Configs of the VLA policy (shared by every stage that runs one) and of the policy commands."""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Literal, get_args

from vlaprobe.configs.env import SuiteName
from vlaprobe.errors import VlaprobeError

Pooling = Literal["last_prompt", "mean_text", "mean_all", "action_tokens"]
"""How each layer's states over the sequence become the recorded vector:

- ``last_prompt``: the state at the last prompt position (the empty token 29871 OpenVLA appends after
  "Out:"), i.e. position T−1 of the prompt pass. It is the state whose logits choose the first action token:
  the last point where the model has read the whole image and instruction and has emitted nothing yet.
  What the paper probed.
- ``mean_text``: the mean over the prompt's text positions (<s> and every prompt token, not the patches).
- ``mean_all``: the mean over all T prompt positions (<s>, 256 patches, prompt tokens).
- ``action_tokens``: for each of the 7 action tokens, the state at the position whose logits choose it
  (T−1 for token 0, then the decode positions T … T+5 where tokens 0 … 5 are fed back): (L, 7, H).
"""

POOLINGS: tuple[Pooling, ...] = get_args(Pooling)


def pooling_of(name: str) -> Pooling:
    """``name`` (e.g. read from a probe folder) as a :data:`Pooling`; one line naming the known ones if unknown."""
    for pooling in POOLINGS:
        if pooling == name:
            return pooling
    raise VlaprobeError(f"unknown pooling {name!r}; use one of {list(POOLINGS)}")


Preprocessing = Literal["numpy", "tf"]
"""LIBERO image pipeline: "numpy" (bit-exact re-implementation) or "tf" (TensorFlow, extra `tf`)."""


@dataclass
class PolicyConfig:
    """Which VLA model to run and how to read its hidden states."""

    model: str = "tiny-libero"
    """"tiny-libero" (the shipped tiny OpenVLA trained on LIBERO-spatial expert demonstrations, the default),
    "tiny-libero-diverse" (the same shape trained on sampled layouts with perturbations, docs/tiny-libero.md),
    "tiny-libero-init" (its network before training: seeded random weights, the control observer), "tiny" (the
    random tiny model with OpenVLA's 256 patches), an OpenVLA checkpoint folder (official HF layout:
    config.json, *.safetensors, dataset_statistics.json, tokenizer.json), or a Hugging Face hub id
    (``openvla/openvla-7b-finetuned-libero-goal``: the loader's files from huggingface_hub's cache, downloaded
    unless ``HF_HUB_OFFLINE=1``; ``HF_HOME`` chooses the cache)."""
    pooling: Pooling = "last_prompt"
    """Hidden state per layer: the last prompt position (the paper's choice), the mean over text or all
    prompt positions, or the 7 positions that choose the action tokens."""
    device: str = "auto"
    """"auto" (CUDA + bf16 when available, else CPU + fp32), "cpu", "cuda" or "cuda:N"."""
    seed: int = 0
    """Seed of the tiny model's weights (ignored for checkpoint folders)."""
    unnorm_key: str | None = None
    """Action statistics to un-normalise with; "<key>_no_noops" is tried next, as OpenVLA's LIBERO eval does.
    Default: the suite's (``--suite libero_goal``: ``libero_goal``, then ``libero_goal_no_noops``, the key of
    OpenVLA's LIBERO-goal fine-tune), or the checkpoint's only key when it has no statistics for the suite."""
    center_crop: bool = True
    """OpenVLA's 0.9-area centre crop (the LIBERO fine-tunes were trained with random crops)."""
    preprocessing: Preprocessing = "numpy"
    """LIBERO image pipeline: "numpy" (bit-exact re-implementation) or "tf" (TensorFlow, extra `tf`)."""


@dataclass
class ModelInfoConfig:
    """Load a policy and print its description as JSON."""

    policy: PolicyConfig = field(default_factory=PolicyConfig)
    """The policy to load."""
    step: bool = False
    """Also run one step on a synthetic 256×256 frame and report the action, tokens and time."""
    instruction: str = "pick up the black bowl between the plate and the ramekin and place it on the plate"
    """Instruction for --step."""
    suite: SuiteName = "libero_spatial"
    """The suite whose action statistics the model un-normalises with (unless --policy.unnorm-key names others)."""


@dataclass
class SaveTinyConfig:
    """Write the seeded tiny OpenVLA as a checkpoint folder."""

    out: Path = Path("tiny-openvla")
    """Folder to write (config.json + model.safetensors); load it back with --policy.model OUT."""
    seed: int = 0
    """Seed of the weights."""
    patch_size: int = 14
    """ViT patch side in pixels of the 224 px image: 14 (256 patches, OpenVLA's and `tiny`'s) or 28 (64 patches,
    the shape of the trained `tiny-libero`; its initial weights: `save-tiny --patch-size 28`)."""
