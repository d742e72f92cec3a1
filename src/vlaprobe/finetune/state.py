"""The run folder of ``vlaprobe finetune``: checkpoints swapped in by rename, training state, metrics.

::

    <out>/finetune.json             the run's settings (a rerun must match them to resume)
    <out>/metrics.jsonl             one JSON line per evaluation
    <out>/summary.json              data sizes, baselines and the last figures (written at the end)
    <out>/checkpoint/               a model folder (config.json, model.safetensors, dataset_statistics.json)
    <out>/checkpoint/training/      state.json, optimizer.safetensors + optimizer.json, adapter (LoRA)

A checkpoint is written whole into ``.checkpoint.partial`` and then renamed into place (the previous one is
renamed aside first and deleted after), so a kill at any moment leaves one complete checkpoint, which
:func:`recover` puts back where it belongs. No pickle: tensors in safetensors, the rest in JSON.
"""

from __future__ import annotations

import json
import os
import shutil
from collections.abc import Callable
from dataclasses import asdict, dataclass
from pathlib import Path

import torch

from vlaprobe.files import JsonObject, write_atomic

CHECKPOINT = "checkpoint"
TRAINING = "training"
PARTIAL = ".checkpoint.partial"
OLD = ".checkpoint.old"
RUN_FILES = frozenset({"finetune.json", "metrics.jsonl", "summary.json", CHECKPOINT})
"""What a run folder may hold (besides hidden temporary names)."""


@dataclass
class TrainState:
    """Where training stands; with the weights and the optimizer, all a resume needs (the sample order
    and the augmentation are functions of the seed and the step)."""

    step: int = 0
    """Optimizer steps taken."""
    loss_sum: float = 0.0
    """Sum of the training losses since the last scheduled evaluation."""
    loss_count: int = 0
    """Steps in ``loss_sum``."""
    accuracy_sum: float = 0.0
    """Sum of the training batches' action-token accuracies over the same steps as ``loss_sum``."""
    elapsed_s: float = 0.0
    """Training wall time so far, over all resumed parts."""


def recover(out: Path) -> None:
    """Finish or undo a checkpoint swap that a kill interrupted; remove partial writes."""
    final, old = out / CHECKPOINT, out / OLD
    if not final.exists() and old.exists():
        os.rename(old, final)
    shutil.rmtree(old, ignore_errors=True)
    shutil.rmtree(out / PARTIAL, ignore_errors=True)


def _optimizer_files(optimizer: torch.optim.Optimizer) -> tuple[dict[str, torch.Tensor], JsonObject]:
    sd = optimizer.state_dict()
    tensors, keys = {}, {}
    for index, state in sd["state"].items():
        keys[str(index)] = sorted(state)
        for name, value in state.items():
            tensors[f"{index}.{name}"] = value.detach().to("cpu").contiguous()
    return tensors, {"param_groups": sd["param_groups"], "state_keys": keys}


def write_checkpoint(
    out: Path,
    write_model: Callable[[Path], None],
    state: TrainState,
    optimizer: torch.optim.Optimizer,
    adapter: tuple[dict[str, torch.Tensor], JsonObject] | None = None,
) -> None:
    """Write the model (``write_model`` fills a folder), the optimizer and ``state``; swap it in by rename."""
    from safetensors.torch import save_file

    partial = out / PARTIAL
    shutil.rmtree(partial, ignore_errors=True)
    training = partial / TRAINING
    training.mkdir(parents=True)
    write_model(partial)
    tensors, meta = _optimizer_files(optimizer)
    save_file(tensors, str(training / "optimizer.safetensors"))
    (training / "optimizer.json").write_text(json.dumps(meta, indent=1) + "\n")
    if adapter is not None:
        save_file(adapter[0], str(training / "adapter_model.safetensors"))
        (training / "adapter_config.json").write_text(json.dumps(adapter[1], indent=2) + "\n")
    (training / "state.json").write_text(json.dumps(asdict(state), indent=2) + "\n")
    final, old = out / CHECKPOINT, out / OLD
    shutil.rmtree(old, ignore_errors=True)
    if final.exists():
        os.rename(final, old)
    os.rename(partial, final)
    shutil.rmtree(old, ignore_errors=True)


def read_train_state(out: Path) -> TrainState | None:
    """The state of the checkpoint in ``out`` (None without one)."""
    path = out / CHECKPOINT / TRAINING / "state.json"
    if not path.is_file():
        return None
    return TrainState(**json.loads(path.read_text()))


def load_optimizer(out: Path, optimizer: torch.optim.Optimizer, device: torch.device) -> None:
    """Restore the optimizer written with the checkpoint in ``out``."""
    from safetensors.torch import load_file

    training = out / CHECKPOINT / TRAINING
    tensors = load_file(str(training / "optimizer.safetensors"), device=str(device))
    meta = json.loads((training / "optimizer.json").read_text())
    state = {
        int(index): {name: tensors[f"{index}.{name}"] for name in names}
        for index, names in meta["state_keys"].items()
    }
    optimizer.load_state_dict({"state": state, "param_groups": meta["param_groups"]})


def read_adapter(out: Path) -> dict[str, torch.Tensor]:
    from safetensors.torch import load_file

    return load_file(str(out / CHECKPOINT / TRAINING / "adapter_model.safetensors"))


def read_metrics(out: Path, up_to_step: int) -> list[JsonObject]:
    """The metric records of ``out`` at or before ``up_to_step`` (later ones belong to a lost part)."""
    path = out / "metrics.jsonl"
    if not path.is_file():
        return []
    records = [json.loads(line) for line in path.read_text().splitlines() if line.strip()]
    return [r for r in records if r["step"] <= up_to_step]


def write_metrics(out: Path, records: list[JsonObject]) -> None:
    write_atomic(out / "metrics.jsonl", "".join(json.dumps(r) + "\n" for r in records))
