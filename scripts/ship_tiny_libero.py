"""Copy a `vlaprobe finetune` checkpoint into the package as the shipped `tiny-libero` observer.

    python scripts/ship_tiny_libero.py runs/tiny-libero/train/checkpoint

Writes ``src/vlaprobe/policies/openvla/weights/tiny-libero/``: ``config.json`` and ``dataset_statistics.json``
as the checkpoint has them (architecture, ``norm_stats``, the training figures) and ``model.safetensors``
with every tensor in float16 (half the size; the loader casts to the run's dtype). The checkpoint's
``training/`` folder (optimizer state for resuming) is not shipped.
"""

from __future__ import annotations

import json
import shutil
import sys
from pathlib import Path

from safetensors.torch import load_file, save_file

from vlaprobe.files import write_atomic
from vlaprobe.policies.openvla.embedded import WEIGHTS

NAME = "tiny-libero"


def ship(checkpoint: Path, target: Path = WEIGHTS / NAME) -> Path:
    config = json.loads((checkpoint / "config.json").read_text())
    if config.get("vlaprobe", {}).get("model_id") != NAME:
        sys.exit(
            f"{checkpoint} was trained with another --model-id than {NAME!r}; see recipes/tiny-libero.yaml"
        )
    tensors = {k: v.half().contiguous() for k, v in load_file(checkpoint / "model.safetensors").items()}
    target.mkdir(parents=True, exist_ok=True)
    write_atomic(target / "model.safetensors", lambda p: save_file(tensors, p, metadata={"format": "pt"}))
    for name in ("config.json", "dataset_statistics.json"):
        shutil.copyfile(checkpoint / name, target / name)
    return target


if __name__ == "__main__":
    if len(sys.argv) != 2:
        sys.exit(__doc__)
    out = ship(Path(sys.argv[1]))
    size = (out / "model.safetensors").stat().st_size / 2**20
    print(f"shipped {sys.argv[1]} → {out} ({size:.1f} MiB)")
