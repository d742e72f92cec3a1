"""scripts/ship_model.py copies a finetune checkpoint into a shipped folder under its model_id, in float16, and
the copy loads by the same code as the checkpoint; a checkpoint of another name is refused in one line."""

from __future__ import annotations

import dataclasses
import importlib.util
from pathlib import Path

import pytest
from safetensors.torch import load_file

from vlaprobe.finetune.command import finetune
from vlaprobe.policies.openvla.policy import OpenVLAPolicy

SCRIPT = Path(__file__).resolve().parents[2] / "scripts" / "ship_model.py"


def _script():
    spec = importlib.util.spec_from_file_location("ship_model", SCRIPT)
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def test_ships_the_checkpoint_under_its_name_in_float16(fast_cfg, tmp_path: Path) -> None:
    cfg = dataclasses.replace(fast_cfg(max_steps=2, eval_every=2), model_id="tiny-libero")
    assert finetune(cfg) == 0
    checkpoint = cfg.out / "checkpoint"
    out = _script().ship(checkpoint, tmp_path / "weights")
    assert out == tmp_path / "weights" / "tiny-libero"
    assert (out / "config.json").read_bytes() == (checkpoint / "config.json").read_bytes()
    full, half = load_file(checkpoint / "model.safetensors"), load_file(out / "model.safetensors")
    assert full.keys() == half.keys()
    for key, tensor in full.items():
        assert half[key].dtype.itemsize == 2 and half[key].shape == tensor.shape
        assert (half[key].float() - tensor.float()).abs().max() <= 1e-2 * max(1.0, tensor.abs().max().item())
    shipped, trained = (
        OpenVLAPolicy.load(str(out), device="cpu"),
        OpenVLAPolicy.load(str(checkpoint), device="cpu"),
    )
    a, b = shipped.describe(), trained.describe()
    assert {**a, "source": None} == {**b, "source": None}  # the same model, loaded by the one loader


def test_refuses_a_checkpoint_that_is_not_a_shipped_name(fast_cfg, tmp_path: Path) -> None:
    cfg = dataclasses.replace(fast_cfg(max_steps=2, eval_every=2), model_id="my-experiment")
    assert finetune(cfg) == 0
    with pytest.raises(SystemExit, match="not a shipped name"):
        _script().ship(cfg.out / "checkpoint", tmp_path / "weights")
    with pytest.raises(SystemExit, match="not a checkpoint folder"):
        _script().ship(tmp_path, tmp_path / "weights")
