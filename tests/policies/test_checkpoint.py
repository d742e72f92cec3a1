"""Checkpoint folders: the official OpenVLA-7B layout, an official-layout folder built here, bad input."""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path

import numpy as np
import pytest
import torch
from safetensors.torch import save_file

from vlaprobe.configs.policy import PolicyConfig
from vlaprobe.errors import VlaprobeError
from vlaprobe.policies import make_policy
from vlaprobe.policies.openvla import checkpoint
from vlaprobe.policies.openvla.config import openvla_7b, to_official
from vlaprobe.policies.openvla.model import OpenVLA
from vlaprobe.policies.openvla.policy import OpenVLAPolicy
from vlaprobe.policies.openvla.tiny import tiny_config, tiny_state_dict

INSTRUCTION = "put both the alphabet soup and the tomato sauce in the basket"


def test_7b_architecture_matches_the_official_layout(reference):
    layout = json.loads((reference / "official_7b_layout.json").read_text())
    with torch.device("meta"):
        model = OpenVLA(openvla_7b())
    ours = {k: list(v.shape) for k, v in model.state_dict().items()}
    assert ours == layout["shapes"]
    assert len(ours) == layout["num_tensors"] == 982
    assert sum(p.numel() for p in model.parameters()) == layout["num_parameters"]
    text = dataclasses.asdict(model.config.text)
    assert {k: text[k] for k in layout["text_config"]} == layout["text_config"]


def _tokenizer_json(folder: Path) -> None:
    from tokenizers import Regex, Tokenizer, pre_tokenizers
    from tokenizers.models import WordLevel

    words = [
        "<unk>",
        "<s>",
        "</s>",
        *sorted(set(f"In : What action should the robot take to {INSTRUCTION} ? Out".split())),
        "\n",
    ]
    tok = Tokenizer(WordLevel({w: i for i, w in enumerate(words)}, unk_token="<unk>"))
    tok.pre_tokenizer = pre_tokenizers.Sequence(
        [
            pre_tokenizers.Split(Regex(r" "), behavior="removed"),
            pre_tokenizers.Split(Regex(r"\w+|[^\w\s]|\n"), "isolated"),
        ]
    )
    tok.save(str(folder / "tokenizer.json"))


def _official_folder(folder: Path) -> tuple[OpenVLAPolicy, Path]:
    """The tiny model written as an official OpenVLA checkpoint: bf16 shards + index, config.json without a
    vlaprobe block, dataset_statistics.json keyed ``libero_spatial_no_noops``, tokenizer.json, and the
    reference's tiny_dims.json for the ViT sizes official config fields cannot express."""
    folder.mkdir()
    cfg = tiny_config()
    state = {k: v.to(torch.bfloat16) for k, v in tiny_state_dict(cfg, 7).items()}
    names = sorted(state)
    half = len(names) // 2
    weight_map = {}
    for i, part in enumerate((names[:half], names[half:]), start=1):
        shard = f"model-0000{i}-of-00002.safetensors"
        save_file({k: state[k] for k in part}, str(folder / shard), metadata={"format": "pt"})
        weight_map.update(dict.fromkeys(part, shard))
    (folder / "model.safetensors.index.json").write_text(
        json.dumps({"metadata": {}, "weight_map": weight_map})
    )
    stale = {"libero_spatial": {"action": {"q01": [0.0] * 7, "q99": [0.0] * 7, "mask": [True] * 6 + [False]}}}
    (folder / "config.json").write_text(json.dumps(to_official(cfg, stale)))
    stats = {
        "action": {
            "q01": [-0.9, -0.8, -0.9, -0.1, -0.2, -0.2, 0.0],
            "q99": [0.9, 0.9, 0.9, 0.1, 0.2, 0.2, 1.0],
        }
    }
    stats["action"]["mask"] = [True] * 6 + [False]
    (folder / "dataset_statistics.json").write_text(json.dumps({"libero_spatial_no_noops": stats}))
    dims = {
        "featurizers": {
            name: {
                "embed_dim": v.embed_dim,
                "depth": v.depth,
                "num_heads": v.num_heads,
                "mlp_hidden_features": v.mlp_hidden,
            }
            for name, v in (("featurizer", cfg.featurizer), ("fused_featurizer", cfg.fused_featurizer))
        }
    }
    (folder / "tiny_dims.json").write_text(json.dumps(dims))
    _tokenizer_json(folder)
    expected_model = checkpoint.build_model(
        cfg, {k: v.float() for k, v in state.items()}, torch.device("cpu"), torch.float32
    )
    return expected_model, folder


def test_official_layout_folder_loads(tmp_path):
    model, folder = _official_folder(tmp_path / "openvla-7b-finetuned-libero-spatial")
    policy = make_policy(PolicyConfig(str(folder), device="cpu"))
    assert policy.model_id == "openvla-7b-finetuned-libero-spatial"
    assert policy.unnorm_key == "libero_spatial_no_noops"  # dataset_statistics.json wins, with the fallback
    assert policy.tokenizer.name.startswith("hf:")
    ours, theirs = model.state_dict(), policy.model.state_dict()
    assert all(torch.equal(ours[k], theirs[k]) for k in ours)
    frame = np.random.default_rng(5).integers(0, 256, (256, 256, 3), dtype=np.uint8)
    step = policy.step(frame, INSTRUCTION)
    ids = policy.prompt_ids(INSTRUCTION)
    assert ids[0, 0] == 1 and ids[0, -1] == 29871 and 0 not in ids[0].tolist()  # every word known
    pred = model.predict(policy.pixel_values(step.model_image), ids, pooling="last_prompt")
    assert step.action_tokens.tolist() == pred.action_token_ids.tolist()
    np.testing.assert_array_equal(step.hidden, pred.hidden.numpy())
    raw = policy.decode(step.action_tokens)
    assert np.all(raw[:6] >= -0.9) and np.all(raw[:6] <= 0.9)  # dataset_statistics.json's range, not config's
    assert step.action[-1] == -np.sign(2 * raw[-1] - 1)


def _one_line(exc: pytest.ExceptionInfo) -> str:
    msg = str(exc.value)
    assert "\n" not in msg
    return msg


def test_bad_folders_are_one_line_errors(tmp_path):
    with pytest.raises(VlaprobeError, match="not found") as err:
        make_policy(PolicyConfig(str(tmp_path / "missing"), device="cpu"))
    _one_line(err)
    with pytest.raises(VlaprobeError, match=r"no config\.json"):
        make_policy(PolicyConfig(str(tmp_path), device="cpu"))
    (tmp_path / "config.json").write_text("{oops")
    with pytest.raises(VlaprobeError, match="cannot read") as err:
        make_policy(PolicyConfig(str(tmp_path), device="cpu"))
    _one_line(err)
    (tmp_path / "config.json").write_text(json.dumps({"model_type": "llava"}))
    with pytest.raises(VlaprobeError, match="not an OpenVLA config"):
        make_policy(PolicyConfig(str(tmp_path), device="cpu"))
    official = to_official(tiny_config(), {})
    (tmp_path / "config.json").write_text(json.dumps({**official, "vision_backbone_id": "siglip-vit-so400m"}))
    with pytest.raises(VlaprobeError, match="unsupported OpenVLA vision backbone"):
        make_policy(PolicyConfig(str(tmp_path), device="cpu"))


def test_broken_checkpoints_are_one_line_errors(tmp_path):
    _, folder = _official_folder(tmp_path / "ckpt")
    (folder / "model-00002-of-00002.safetensors").rename(folder / "elsewhere.safetensors")
    with pytest.raises(VlaprobeError, match="missing from") as err:
        make_policy(PolicyConfig(str(folder), device="cpu"))
    _one_line(err)
    (folder / "elsewhere.safetensors").rename(folder / "model-00002-of-00002.safetensors")

    original = (folder / "config.json").read_text()
    config = json.loads(original)
    config["text_config"]["hidden_size"] *= 2
    (folder / "config.json").write_text(json.dumps(config))
    with pytest.raises(VlaprobeError, match="does not belong to these weights") as err:
        make_policy(PolicyConfig(str(folder), device="cpu"))
    _one_line(err)
    config = json.loads(original)
    config["text_config"]["num_hidden_layers"] = 30
    (folder / "config.json").write_text(json.dumps(config))
    with pytest.raises(VlaprobeError, match="unexpected"):
        make_policy(PolicyConfig(str(folder), device="cpu"))
    (folder / "config.json").write_text(original)

    (folder / "tokenizer.json").unlink()
    with pytest.raises(VlaprobeError, match="tokenizer"):
        make_policy(PolicyConfig(str(folder), device="cpu"))
    _tokenizer_json(folder)
    with pytest.raises(VlaprobeError, match="libero_goal"):
        make_policy(PolicyConfig(str(folder), device="cpu", unnorm_key="libero_goal"))
    with pytest.raises(VlaprobeError, match="pooling"):
        make_policy(PolicyConfig(str(folder), pooling="max", device="cpu"))  # type: ignore[arg-type]
    if not torch.cuda.is_available():
        with pytest.raises(VlaprobeError, match="CUDA is not available"):
            make_policy(PolicyConfig("tiny", device="cuda"))
    with pytest.raises(VlaprobeError, match="unknown device"):
        make_policy(PolicyConfig("tiny", device="gpu0"))


def test_commands(tmp_path, capsys):
    from typing import get_args, get_type_hints

    from vlaprobe.configs.policy import ModelInfoConfig, PolicyConfig, SaveTinyConfig
    from vlaprobe.policies.base import Pooling
    from vlaprobe.policies.openvla.commands import model_info, save_tiny

    assert get_args(get_type_hints(PolicyConfig)["pooling"]) == get_args(Pooling)
    assert save_tiny(SaveTinyConfig(out=tmp_path / "tiny", seed=3)) == 0
    capsys.readouterr()
    cfg = ModelInfoConfig(
        policy=PolicyConfig(model=str(tmp_path / "tiny"), device="cpu", pooling="mean_all"), step=True
    )
    assert model_info(cfg) == 0
    info = json.loads(capsys.readouterr().out)
    assert info["model_id"] == "tiny-openvla-seed3" and info["pooling"] == "mean_all"
    assert info["step"]["hidden_shape"] == [33, info["hidden_size"]] and len(info["step"]["action"]) == 7
