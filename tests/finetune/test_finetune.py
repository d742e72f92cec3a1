"""`vlaprobe finetune` end to end on a small store: learning, determinism, resume, checkpoints, LoRA."""

from __future__ import annotations

import dataclasses
import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
import torch
from safetensors.torch import load_file

from vlaprobe.configs.policy import PolicyConfig
from vlaprobe.finetune.command import build_trainer, finetune
from vlaprobe.finetune.data import load_demonstrations, split_episodes
from vlaprobe.finetune.evaluate import validate
from vlaprobe.policies.factory import make_policy
from vlaprobe.policies.openvla import checkpoint
from vlaprobe.policies.openvla.actions import encode_action, normalize_action, training_gripper

LOSSES = ("train_loss", "train_accuracy", "val_loss", "val_accuracy", "val_l1", "val_l1_normalized")


def metrics(out: Path) -> list[dict]:
    return [json.loads(line) for line in (out / "metrics.jsonl").read_text().splitlines()]


def figures(out: Path) -> list[tuple]:
    """The computed figures of every scheduled record (timings left out)."""
    return [(r["step"], *(r[k] for k in LOSSES)) for r in metrics(out) if "stopped" not in r]


def weights(out: Path) -> dict[str, torch.Tensor]:
    return load_file(str(out / "checkpoint" / "model.safetensors"))


def assert_same_weights(a: Path, b: Path) -> None:
    wa, wb = weights(a), weights(b)
    assert wa.keys() == wb.keys()
    assert all(torch.equal(wa[k], wb[k]) for k in wa)


def test_loss_goes_down_and_the_checkpoint_loads(fast_cfg) -> None:
    cfg = fast_cfg(max_steps=24, eval_every=6)
    assert finetune(cfg) == 0
    records = metrics(cfg.out)
    assert [r["step"] for r in records] == [6, 12, 18, 24]
    assert records[-1]["val_loss"] < records[0]["val_loss"] - 0.5
    assert records[-1]["train_loss"] < records[0]["train_loss"] - 0.5
    summary = json.loads((cfg.out / "summary.json").read_text())
    assert summary["finished"] and summary["state"]["step"] == 24
    assert records[-1]["val_accuracy"] > records[0]["val_accuracy"]
    assert 0 <= records[0]["train_accuracy"] < records[-1]["train_accuracy"] <= 1
    policy = make_policy(PolicyConfig(model=str(cfg.out / "checkpoint"), device="cpu"))
    step = policy.step(np.zeros((32, 32, 3), dtype=np.uint8), "put the bowl number 1 on the plate")
    assert step.action.shape == (7,) and np.isfinite(step.action).all()


def test_norm_stats_round_trip_through_the_checkpoint(fast_cfg) -> None:
    cfg = fast_cfg(max_steps=2, eval_every=2)
    finetune(cfg)
    folder = cfg.out / "checkpoint"
    _, norm_stats, block = checkpoint.read_config(folder)  # dataset_statistics.json, as OpenVLA's eval reads
    in_config = json.loads((folder / "config.json").read_text())["norm_stats"]
    assert norm_stats == in_config and list(norm_stats) == ["libero_spatial"]
    stats = norm_stats["libero_spatial"]["action"]
    assert stats["mask"] == [True] * 6 + [False]
    demos = load_demonstrations(cfg.stores, 28)
    split = split_episodes(demos, cfg.val_fraction, cfg.seed)
    train = demos.actions[split.train]
    np.testing.assert_allclose(stats["q01"], np.quantile(train, 0.01, axis=0))
    np.testing.assert_allclose(stats["q99"], np.quantile(train, 0.99, axis=0))
    assert norm_stats["libero_spatial"]["num_transitions"] == len(split.train)
    assert block["finetune"]["step"] == 2

    policy = make_policy(PolicyConfig(model=str(folder), device="cpu"))
    q01, q99, mask = (np.asarray(stats[k]) for k in ("q01", "q99", "mask"))
    inside = np.clip(train, q01, q99)  # binning clips to the statistics' range
    decoded = policy.decode(encode_action(normalize_action(inside, q01, q99, mask)))
    half_bin = (q99 - q01) / 255 + 1e-9
    assert (np.abs(decoded - inside)[:, :6] <= half_bin[:6]).all()
    assert (np.abs(decoded[:, 6] - inside[:, 6]) < 0.01).all()  # the gripper: 0 or 1 to a bin centre


def test_two_runs_are_identical(fast_cfg, tmp_path: Path) -> None:
    a, b = (fast_cfg(out=tmp_path / name, augment=True, max_steps=6, eval_every=3) for name in "ab")
    finetune(a)
    finetune(b)
    assert figures(a.out) == figures(b.out)
    assert_same_weights(a.out, b.out)


def test_a_stopped_run_resumes_to_the_uninterrupted_result(fast_cfg, tmp_path: Path) -> None:
    whole = fast_cfg(out=tmp_path / "whole")
    finetune(whole)
    parts = fast_cfg(out=tmp_path / "parts", max_minutes=1e-9)  # stops right after step 1, at a checkpoint
    finetune(parts)
    assert json.loads((parts.out / "checkpoint/training/state.json").read_text())["step"] == 1
    assert metrics(parts.out)[-1]["stopped"] == "max_minutes"
    finetune(fast_cfg(out=tmp_path / "parts"))
    assert figures(parts.out) == figures(whole.out)
    assert_same_weights(parts.out, whole.out)


def test_kill_9_and_rerun_resume_from_the_last_checkpoint(fast_cfg, tmp_path: Path) -> None:
    whole = fast_cfg(out=tmp_path / "whole", max_steps=8, eval_every=2)
    finetune(whole)
    out = tmp_path / "killed"
    args = [
        *("--stores", str(whole.stores[0]), "--model", whole.model, "--out", str(out)),
        *(
            "--batch-size",
            "8",
            "--max-steps",
            "8",
            "--eval-every",
            "2",
            "--warmup-steps",
            "2",
            "--lr",
            "2e-3",
        ),
        *("--threads", "1", "--no-progress", "--val-fraction", "0.25"),
    ]
    env = {**os.environ, "PYTHONPATH": os.pathsep.join(sys.path)}
    proc = subprocess.Popen([sys.executable, "-m", "vlaprobe.cli", "finetune", *args], env=env)
    state = out / "checkpoint" / "training" / "state.json"
    deadline = time.monotonic() + 120
    while not state.exists() and proc.poll() is None and time.monotonic() < deadline:
        time.sleep(0.02)
    proc.send_signal(signal.SIGKILL)
    proc.wait()
    assert not (out / "summary.json").exists(), "the run ended before it could be killed"
    from vlaprobe.cli import main

    assert main(["finetune", *args]) == 0
    assert figures(out) == figures(whole.out)
    assert_same_weights(out, whole.out)


def test_lora_trains_only_adapters_and_writes_merged_weights(fast_cfg, small_model: Path) -> None:
    cfg = fast_cfg(lora=True, lora_rank=4, lr=5e-3)
    finetune(cfg)
    records = metrics(cfg.out)
    assert records[-1]["val_loss"] < records[0]["val_loss"]
    base, merged = load_file(str(small_model / "model.safetensors")), weights(cfg.out)
    assert base.keys() == merged.keys()
    changed = {k for k in base if not torch.equal(base[k], merged[k])}
    adapted = {f"{name}.weight" for name in _lora_targets(small_model)}
    assert changed and changed <= adapted  # biases, norms, embeddings, lm_head, convs: untouched
    adapter = load_file(str(cfg.out / "checkpoint/training/adapter_model.safetensors"))
    assert all(k.startswith("base_model.model.") and ".lora_" in k for k in adapter)
    assert len(adapter) == 2 * len(adapted)
    policy = make_policy(PolicyConfig(model=str(cfg.out / "checkpoint"), device="cpu"))
    assert sum(p.numel() for p in policy.model.parameters()) == sum(v.numel() for v in base.values())


def test_lora_resume_matches_the_uninterrupted_run(fast_cfg, tmp_path: Path) -> None:
    whole = fast_cfg(out=tmp_path / "whole", lora=True, lora_rank=4, max_steps=6, eval_every=3)
    finetune(whole)
    parts = fast_cfg(
        out=tmp_path / "parts", lora=True, lora_rank=4, max_steps=6, eval_every=3, max_minutes=1e-9
    )
    finetune(parts)
    finetune(fast_cfg(out=tmp_path / "parts", lora=True, lora_rank=4, max_steps=6, eval_every=3))
    assert figures(parts.out) == figures(whole.out)
    assert_same_weights(parts.out, whole.out)


def test_frozen_vision_keeps_the_featurisers(fast_cfg, small_model: Path) -> None:
    cfg = fast_cfg(freeze_vision=True)
    finetune(cfg)
    base, trained = load_file(str(small_model / "model.safetensors")), weights(cfg.out)
    vision = [k for k in base if k.startswith("vision_backbone.")]
    assert vision and all(torch.equal(base[k], trained[k]) for k in vision)
    assert not torch.equal(base["projector.fc1.weight"], trained["projector.fc1.weight"])
    assert metrics(cfg.out)[-1]["val_loss"] < metrics(cfg.out)[0]["val_loss"]


def _lora_targets(folder: Path) -> list[str]:
    from vlaprobe.finetune.lora import lora_targets
    from vlaprobe.policies.openvla.model import OpenVLA

    with torch.device("meta"):
        return lora_targets(OpenVLA(checkpoint.read_config(folder)[0]))


@pytest.mark.parametrize("gripper, target", [(-1.0, 1.0), (1.0, 0.0), (0.0, 1.0)])
def test_gripper_target_is_openvlas(gripper: float, target: float) -> None:
    action = np.array([0.1, 0, 0, 0, 0, 0, gripper])
    assert training_gripper(action)[6] == target


def test_lora_on_an_official_checkpoint_folder_keeps_its_layout(shared_dir: Path, tmp_path: Path) -> None:
    """The path of a real OpenVLA fine-tune: an official folder (Llama tokenizer.json, no "vlaprobe" block)
    in, LoRA, and an official folder out that our loader (and OpenVLA's own code) reads."""
    import shutil

    from tests.finetune.helpers import write_demo_store
    from tokenizers import Tokenizer, models, pre_tokenizers

    from vlaprobe.configs.finetune import FinetuneConfig

    source = tmp_path / "openvla"
    source.mkdir()
    for name in ("config.json", "model.safetensors", "tiny_dims.json", "preprocessor_config.json"):
        shutil.copy(shared_dir / "openvla_reference" / name, source / name)
    words = [
        "in",
        ":",
        "what",
        "action",
        "should",
        "the",
        "robot",
        "take",
        "to",
        "put",
        "bowl",
        "number",
        "0",
        "1",
        "on",
        "plate",
        "?",
        "out",
    ]
    tok = Tokenizer(
        models.WordLevel({"<unk>": 0, "<s>": 1, **{w: 100 + i for i, w in enumerate(words)}}, "<unk>")
    )
    tok.pre_tokenizer = pre_tokenizers.Whitespace()
    tok.save(str(source / "tokenizer.json"))
    store = write_demo_store(
        tmp_path / "demos", [(t, i, 3) for t in range(2) for i in range(2)], image_size=224
    )
    cfg = FinetuneConfig(
        stores=(store,),
        out=tmp_path / "run",
        model=str(source),
        lora=True,
        lora_rank=2,
        batch_size=2,
        max_steps=2,
        warmup_steps=1,
        threads=1,
        progress=False,
        val_fraction=0.5,
        dataset_name="mine",
    )
    assert finetune(cfg) == 0
    folder = cfg.out / "checkpoint"
    config = json.loads((folder / "config.json").read_text())
    assert "vlaprobe" not in config and set(config["norm_stats"]) == {"libero_spatial", "mine"}
    assert (folder / "tokenizer.json").is_file() and (folder / "tiny_dims.json").is_file()
    assert {v.dtype for v in weights(cfg.out).values()} == {torch.bfloat16}  # the source's torch_dtype
    policy = make_policy(PolicyConfig(model=str(folder), device="cpu", unnorm_key="mine"))
    assert policy.tokenizer.name.startswith("hf:")
    step = policy.step(np.zeros((64, 64, 3), dtype=np.uint8), "put the bowl number 1 on the plate")
    assert step.action.shape == (7,)


def test_train_accuracy_is_the_batch_accuracy_before_the_update(fast_cfg) -> None:
    """OpenVLA's logged ``action_accuracy``: the step-1 record's is the first batch's, with the start weights."""
    cfg = fast_cfg(max_steps=1, eval_every=1)
    trainer, _ = build_trainer(dataclasses.replace(cfg, out=cfg.out.with_name("probe")))
    rows = trainer.rows(0)
    before = validate(trainer.model, trainer.examples, rows, trainer.stats, trainer.device, len(rows))
    assert finetune(cfg) == 0
    (record,) = metrics(cfg.out)
    assert record["train_accuracy"] == pytest.approx(before.accuracy, abs=1e-9)
