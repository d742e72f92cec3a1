"""Checkpoints by Hugging Face hub id (``openvla/openvla-7b-finetuned-libero-goal``), through huggingface_hub's cache.

A ``--policy.model`` that is neither a model name nor an existing folder but reads ``owner/name`` is a hub id. Its
folder is the snapshot in huggingface_hub's cache (``HF_HOME``/``HF_HUB_CACHE`` choose where; ``HF_HUB_OFFLINE=1``
never asks the network), holding only the files the loader reads (:data:`LOADER_FILES`: not OpenVLA's
``modeling_*.py``, ``tokenizer.model`` or processor files). A missing download is one line naming the command that
fetches it.
"""

from __future__ import annotations

import re
from pathlib import Path

from vlaprobe.errors import VlaprobeError

LOADER_FILES = (
    "config.json",
    "dataset_statistics.json",
    "tokenizer.json",
    "tiny_dims.json",
    "model.safetensors.index.json",
    "*.safetensors",
)
"""The files :mod:`vlaprobe.policies.openvla.checkpoint` and the tokenizer read (glob patterns)."""

_HUB_ID = re.compile(r"[A-Za-z0-9][A-Za-z0-9_.-]*/[A-Za-z0-9][A-Za-z0-9_.-]*")


def is_hub_id(model: str) -> bool:
    """``owner/name`` that is not an existing path (a relative folder of that shape wins)."""
    return bool(_HUB_ID.fullmatch(model)) and not Path(model).exists() and ".." not in model


def model_folder(model: str) -> Path | None:
    """The checkpoint folder ``--model`` names: a shipped model's, a hub id's cached snapshot, else the path
    itself; None for a model built from a seed ("tiny", "tiny-libero-init")."""
    from vlaprobe.policies.openvla.embedded import SEEDED_MODELS, embedded_folder

    if model in SEEDED_MODELS:
        return None
    return embedded_folder(model) or (hub_folder(model) if is_hub_id(model) else Path(model))


def download_command(repo_id: str) -> str:
    """The command that puts ``repo_id``'s loader files into the cache (``hf`` is huggingface_hub's CLI)."""
    return f"hf download {repo_id} --include {' '.join(repr(p) for p in LOADER_FILES)}"


def hub_folder(repo_id: str, revision: str | None = None) -> Path:
    """The cached snapshot folder of ``repo_id`` with the loader's files: read from the cache when
    ``HF_HUB_OFFLINE`` is set (or the hub cannot be reached), else downloaded into it first."""
    from huggingface_hub import constants, snapshot_download
    from huggingface_hub.errors import HfHubHTTPError, LocalEntryNotFoundError, RepositoryNotFoundError

    try:
        folder = Path(
            snapshot_download(
                repo_id,
                revision=revision,
                allow_patterns=list(LOADER_FILES),
                local_files_only=constants.HF_HUB_OFFLINE,
            )
        )
    except (LocalEntryNotFoundError, RepositoryNotFoundError, HfHubHTTPError, OSError) as exc:
        where = (
            "not in the Hugging Face cache" if constants.HF_HUB_OFFLINE else "neither cached nor downloadable"
        )
        raise VlaprobeError(
            f"model {repo_id} is no folder and {where} ({constants.HF_HUB_CACHE}; {type(exc).__name__}); fetch "
            f"it with `{download_command(repo_id)}` (HF_HOME chooses the cache), or pass a checkpoint folder"
        ) from None
    missing = [name for name in ("config.json", "*.safetensors") if not any(folder.glob(name))]
    if missing:
        raise VlaprobeError(
            f"the cached snapshot of {repo_id} ({folder}) lacks {' and '.join(missing)}; fetch it with "
            f"`{download_command(repo_id)}`"
        )
    return folder
