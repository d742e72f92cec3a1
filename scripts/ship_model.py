"""Copy a `vlaprobe finetune` checkpoint into the package as a shipped observer, loadable by name.

    python scripts/ship_model.py runs/tiny-libero/train/checkpoint            # → weights/tiny-libero/
    python scripts/ship_model.py runs/tiny-libero-diverse/train/checkpoint    # → weights/tiny-libero-diverse/

The name is the checkpoint's ``--model-id`` (its recipe's ``model_id``), which must be one of the shipped names
(``vlaprobe.policies.openvla.embedded.EMBEDDED_MODELS``). Writes ``src/vlaprobe/policies/openvla/weights/<name>/``:
``config.json`` and ``dataset_statistics.json`` as the checkpoint has them (architecture, ``norm_stats``, the
training figures) and ``model.safetensors`` with every tensor in float16 (half the size; the loader casts to the
run's dtype). The checkpoint's ``training/`` folder (optimizer state for resuming) is not shipped.
"""

from __future__ import annotations

import json
import shutil
import sys
from pathlib import Path

from safetensors.torch import load_file, save_file

from vlaprobe.files import write_atomic
from vlaprobe.policies.openvla.embedded import EMBEDDED_MODELS, WEIGHTS


def ship(checkpoint: Path, weights: Path = WEIGHTS) -> Path:
    """Write the float16 copy of ``checkpoint`` under ``weights/<its model_id>``; exit with one line otherwise."""
    if not (checkpoint / "config.json").is_file():
        sys.exit(f"{checkpoint} is not a checkpoint folder (no config.json); pass <finetune out>/checkpoint")
    config = json.loads((checkpoint / "config.json").read_text())
    name = config.get("vlaprobe", {}).get("model_id")
    if name not in EMBEDDED_MODELS:
        sys.exit(
            f"{checkpoint} was trained with --model-id {name!r}, not a shipped name ({', '.join(EMBEDDED_MODELS)});"
            " train it with its recipe in recipes/"
        )
    tensors = {k: v.half().contiguous() for k, v in load_file(checkpoint / "model.safetensors").items()}
    target = weights / name
    target.mkdir(parents=True, exist_ok=True)
    write_atomic(target / "model.safetensors", lambda p: save_file(tensors, p, metadata={"format": "pt"}))
    for file in ("config.json", "dataset_statistics.json"):
        shutil.copyfile(checkpoint / file, target / file)
    return target


if __name__ == "__main__":
    if len(sys.argv) != 2:
        sys.exit(__doc__)
    out = ship(Path(sys.argv[1]))
    size = (out / "model.safetensors").stat().st_size / 2**20
    print(f"shipped {sys.argv[1]} → {out} ({size:.1f} MiB)")
