"""The model to fine-tune (through the policy loader, so the tokenizer and layout are the policy's own) and
the model folder each checkpoint writes (loadable by ``--policy.model`` and by OpenVLA's own code)."""

from __future__ import annotations

import json
import shutil
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import torch

from vlaprobe.files import JsonObject, write_atomic
from vlaprobe.policies.openvla import checkpoint
from vlaprobe.policies.openvla.config import OpenVLAConfig
from vlaprobe.policies.openvla.model import OpenVLA
from vlaprobe.policies.openvla.tokenizer import Tokenizer, WordHashTokenizer

OFFICIAL_SKIP = frozenset({"config.json", "model.safetensors.index.json", "dataset_statistics.json"})
"""Files of an official source folder a checkpoint does not copy (it writes its own)."""


@dataclass
class Initial:
    """The starting model and what writing it back needs."""

    model: OpenVLA
    """The network (on the training device)."""
    tokenizer: Tokenizer
    """The tokenizer the policy uses with it."""
    source: Path | None
    """The checkpoint folder it came from (None: the seeded tiny model)."""
    official: bool
    """True for an official OpenVLA folder (no "vlaprobe" block): checkpoints keep its config.json and
    tokenizer/processor files."""


def _folder(model: str) -> Path | None:
    """The checkpoint folder ``--model`` names (a shipped model's, a hub id's cached snapshot or a path); None
    for a seeded name."""
    from vlaprobe.policies.openvla.hub import model_folder

    return model_folder(model)


def architecture(model: str) -> OpenVLAConfig:
    """The architecture ``--model`` names, read without loading weights (one-line errors for bad folders)."""
    from vlaprobe.policies.openvla.embedded import SEEDED_MODELS
    from vlaprobe.policies.openvla.tiny import tiny_config

    folder = _folder(model)
    if folder is None:
        return tiny_config(patch_size=SEEDED_MODELS[model])
    return checkpoint.read_config(folder)[0]


def load_initial(model: str, seed: int, device: str, full_precision: bool) -> Initial:
    """Load ``--model``; ``full_precision`` casts bf16 weights (CUDA's default) to float32 for a full fine-tune."""
    from vlaprobe.policies.openvla.policy import OpenVLAPolicy

    policy = OpenVLAPolicy.load(model, device=device, seed=seed)
    net = policy.model.float() if full_precision else policy.model
    source = _folder(model)
    official = source is not None and not checkpoint.read_config(source)[2]
    return Initial(net, policy.tokenizer, source, official)


DTYPES = {"bfloat16": torch.bfloat16, "float16": torch.float16, "float32": torch.float32}
"""config.json ``torch_dtype`` values a merged LoRA checkpoint is stored in."""


def _write_official(
    folder: Path, source: Path, state: dict[str, torch.Tensor], norm_stats: JsonObject, merged: bool
) -> None:
    from safetensors.torch import save_file

    raw = json.loads((source / "config.json").read_text())
    raw["norm_stats"] = {**(raw.get("norm_stats") or {}), **norm_stats}
    # merged LoRA weights go back in the source's dtype (bf16 for OpenVLA: 15 GB, not 30); a full fine-tune
    # keeps float32 so that resuming from the checkpoint is exact
    dtype = DTYPES.get(str(raw.get("torch_dtype")), torch.float32) if merged else torch.float32
    if not merged:
        raw["torch_dtype"] = "float32"
    tensors = {k: v.detach().to("cpu", dtype).contiguous() for k, v in state.items()}
    write_atomic(folder / "model.safetensors", lambda p: save_file(tensors, p, metadata={"format": "pt"}))
    write_atomic(folder / "config.json", json.dumps(raw, indent=2) + "\n")
    for path in sorted(source.iterdir()):
        if (
            path.is_file()
            and path.suffix in (".json", ".model", ".py", ".txt")
            and path.name not in OFFICIAL_SKIP
        ):
            shutil.copy2(path, folder / path.name)


def model_writer(
    init: Initial,
    state: Callable[[], dict[str, torch.Tensor]],
    norm_stats: JsonObject,
    model_id: str,
    info: Callable[[], JsonObject],
    merged: bool = False,
) -> Callable[[Path], None]:
    """A function that writes the current weights (``state()``) as a model folder into a given folder;
    ``merged``: LoRA-merged weights (an official folder stores them in its own dtype).

    vlaprobe's own models keep the "vlaprobe" block (architecture, tokenizer, ``model_id``, and ``info()``
    under "finetune"); official ones keep their config.json with the new statistics merged into
    ``norm_stats``. Both get ``dataset_statistics.json``, which OpenVLA's LIBERO evaluation and our loader
    prefer.
    """

    def write(folder: Path) -> None:
        if init.official:
            assert init.source is not None
            _write_official(folder, init.source, state(), norm_stats, merged)
        else:
            extra = {
                "tokenizer": WordHashTokenizer.name,
                "model_id": model_id,
                "seed": None,
                "finetune": info(),
            }
            checkpoint.save_checkpoint(folder, init.model, norm_stats, extra, state())
        write_atomic(folder / "dataset_statistics.json", json.dumps(norm_stats, indent=2) + "\n")

    return write


def full_state(model: torch.nn.Module) -> dict[str, torch.Tensor]:
    """The model's weights as float32 CPU tensors (a full fine-tune's checkpoint)."""
    return {k: v.detach().to("cpu", torch.float32) for k, v in model.state_dict().items()}


def load_weights(model: torch.nn.Module, folder: Path) -> None:
    """Copy a checkpoint's weights into ``model`` in place (the optimizer keeps its parameter objects)."""
    param = next(model.parameters())
    tensors = checkpoint.read_state_dict(folder, param.device, param.dtype)
    model.load_state_dict(tensors, strict=True)
