"""``vlaprobe finetune``: checks, data, model, optimizer, resume, then the loop (:mod:`vlaprobe.finetune.loop`)."""

from __future__ import annotations

import dataclasses
import json
from dataclasses import asdict
from pathlib import Path

import numpy as np
import torch

from vlaprobe.configs import config_to_dict
from vlaprobe.configs.env import same_suite
from vlaprobe.configs.finetune import FinetuneConfig
from vlaprobe.errors import VlaprobeError
from vlaprobe.files import JsonObject, write_atomic
from vlaprobe.finetune import lora as lora_mod
from vlaprobe.finetune import model_io
from vlaprobe.finetune.checks import check_finetune, check_run_folder
from vlaprobe.finetune.data import (
    Demonstrations,
    Split,
    dataset_statistics,
    load_demonstrations,
    split_episodes,
)
from vlaprobe.finetune.examples import (
    ActionStats,
    cache_features,
    longest_sequence,
    majority_accuracy,
    make_examples,
)
from vlaprobe.finetune.loop import Trainer, make_schedule
from vlaprobe.finetune.objective import step_forward
from vlaprobe.finetune.state import (
    CHECKPOINT,
    TrainState,
    load_optimizer,
    read_adapter,
    read_metrics,
    read_train_state,
)
from vlaprobe.locks import lock_folder


def _stats_of(norm_stats: JsonObject, name: str) -> ActionStats:
    a = norm_stats[name]["action"]
    return ActionStats(np.asarray(a["q01"]), np.asarray(a["q99"]), np.asarray(a["mask"], dtype=bool))


def _check_same_data(cfg: FinetuneConfig, name: str, norm_stats: JsonObject) -> None:
    saved = json.loads((cfg.out / CHECKPOINT / "dataset_statistics.json").read_text())
    if saved.get(name) != json.loads(json.dumps(norm_stats[name])):
        raise VlaprobeError(
            f"--out {cfg.out} was trained on other data (its action statistics differ from these stores'); "
            "pass the same --stores to resume, or choose a new --out"
        )


def _check_compiler(device: torch.device) -> None:
    """--compile on a CPU writes C++ kernels: refuse before loading anything when no compiler is found."""
    import os
    import shutil

    wanted = os.environ.get("CXX", "")
    if device.type == "cpu" and not any(shutil.which(c) for c in (wanted, "g++", "c++", "clang++") if c):
        raise VlaprobeError(
            "--compile on a CPU needs a C++ compiler (g++, c++ or clang++ on PATH, or $CXX); "
            "install one (apt-get install g++) or drop --compile"
        )


def _data(cfg: FinetuneConfig, name: str, image_size: int) -> tuple[Demonstrations, Split, JsonObject]:
    """The demonstrations, their split and the training split's statistics (``norm_stats``, key ``name``)."""
    demos = load_demonstrations(
        cfg.stores, image_size, cfg.success_only, cfg.skip_post_success, cfg.drop_noops, cfg.tasks
    )
    split = split_episodes(demos, cfg.val_fraction, cfg.seed, cfg.val_max_samples)
    if len(split.train) < cfg.batch_size:
        raise VlaprobeError(
            f"the training split has {len(split.train)} rows, fewer than --batch-size {cfg.batch_size}; "
            "lower --batch-size or collect more episodes"
        )
    return demos, split, {name: dataset_statistics(demos, split.train, len(split.train_episodes))}


def _restore(
    cfg: FinetuneConfig,
    model: torch.nn.Module,
    optimizer: torch.optim.Optimizer,
    lora: bool,
    device: torch.device,
) -> tuple[TrainState, list[JsonObject]]:
    """Weights (or the adapter), optimizer, state and metric records of the checkpoint in ``--out``."""
    state = read_train_state(cfg.out) or TrainState()
    if lora:
        lora_mod.load_adapter(model, {k: v.to(device) for k, v in read_adapter(cfg.out).items()})
    else:
        model_io.load_weights(model, cfg.out / CHECKPOINT)
    load_optimizer(cfg.out, optimizer, device)
    return state, read_metrics(cfg.out, state.step)


def with_stores_suite(cfg: FinetuneConfig) -> tuple[FinetuneConfig, str]:
    """``cfg`` with ``dataset_name`` filled in (default: the stores' suite, the key ``--suite`` looks for when the
    model runs) and that name; the stores must be collection stores of one suite."""
    from vlaprobe.collection.store import StoreMeta, read_meta

    metas = [
        StoreMeta.parse(read_meta(path, hint="pass the --out folder of a `vlaprobe collect` run to --stores"))
        for path in cfg.stores
    ]
    for path, meta in zip(cfg.stores[1:], metas[1:], strict=True):
        same_suite(f"store {cfg.stores[0]}", metas[0].suite, f"store {path}", meta.suite)
    name = cfg.dataset_name or (metas[0].suite if metas else "libero_spatial")
    return dataclasses.replace(cfg, dataset_name=name), name


def build_trainer(cfg: FinetuneConfig) -> tuple[Trainer, JsonObject]:
    """Everything up to the first step; every input problem is a one-line error before any training."""
    from vlaprobe import devices

    check_finetune(cfg)
    cfg, name = with_stores_suite(cfg)
    device = devices.resolve_device(cfg.device)
    if cfg.compile:
        _check_compiler(device)
    arch = model_io.architecture(cfg.model)
    resuming = check_run_folder(cfg, arch)
    if cfg.threads is not None:
        torch.set_num_threads(cfg.threads)
    demos, split, norm_stats = _data(cfg, name, arch.featurizer.image_size)
    if resuming:
        _check_same_data(cfg, name, norm_stats)
    stats = _stats_of(norm_stats, name)
    init = model_io.load_initial(cfg.model, cfg.model_seed, str(device), full_precision=not cfg.lora)
    model = init.model
    lora_config = lora_mod.add_lora(model, cfg.lora_rank, cfg.lora_dropout, cfg.seed) if cfg.lora else None
    if cfg.freeze_vision:
        model.vision_backbone.requires_grad_(False)
    examples = make_examples(demos, init.tokenizer, stats, model)
    if cfg.compile:
        examples.width = longest_sequence(examples)
    if cfg.freeze_vision:
        cache_features(examples, model, device)
        demos.images = demos.images[:0]  # the cached features replace them
    params = [p for p in model.parameters() if p.requires_grad]
    # fused: one kernel over all tensors (5x faster than the per-tensor loop on the CPU, same arithmetic per step)
    optimizer = torch.optim.AdamW(params, lr=cfg.lr, weight_decay=cfg.weight_decay, fused=True)
    schedule = make_schedule(cfg, len(split.train))
    state, records = (
        _restore(cfg, model, optimizer, lora_config is not None, device) if resuming else (TrainState(), [])
    )
    info = {
        "train_rows": len(split.train),
        "val_rows": len(split.val),
        "train_episodes": len(split.train_episodes),
        "val_episodes": len(split.val_episodes),
        "trainable_parameters": sum(p.numel() for p in params),
        "majority_accuracy": majority_accuracy(examples.tokens, split.train, split.val),
        "steps": schedule.total,
        "steps_per_epoch": schedule.steps_per_epoch,
        "resumed_at_step": state.step,
    }
    model_id = cfg.model_id or cfg.out.resolve().name
    state_fn = (
        (lambda: lora_mod.merged_state_dict(model)) if cfg.lora else (lambda: model_io.full_state(model))
    )
    writer = model_io.model_writer(
        init,
        state_fn,
        norm_stats,
        model_id,
        lambda: {"step": trainer.state.step, "dataset_name": cfg.dataset_name},
        merged=cfg.lora,
    )
    adapter = (
        (lambda: (lora_mod.adapter_state_dict(model), lora_mod.adapter_config_json(lora_config)))
        if lora_config is not None
        else None
    )
    trainer = Trainer(
        cfg,
        model,
        examples,
        split,
        stats,
        device,
        schedule,
        optimizer,
        writer,
        adapter,
        records,
        state,
        step_forward(model, cfg.compile),
    )
    return trainer, info


def finetune(cfg: FinetuneConfig) -> int:
    """Fine-tune, checkpoint, and print where the model is; returns the exit status."""
    cfg = dataclasses.replace(cfg, stores=tuple(Path(p) for p in cfg.stores), out=Path(cfg.out))
    with lock_folder(cfg.out):  # a second fine-tune into the same folder is refused, not interleaved
        return _finetune(cfg)


def _finetune(cfg: FinetuneConfig) -> int:
    check_finetune(cfg)
    cfg = with_stores_suite(cfg)[0]  # finetune.json records the statistics key used
    trainer, info = build_trainer(cfg)
    out = cfg.out
    out.mkdir(parents=True, exist_ok=True)
    write_atomic(out / "finetune.json", json.dumps(config_to_dict(cfg), indent=2) + "\n")
    print(
        f"fine-tuning {cfg.model} on {info['train_rows']} rows ({info['train_episodes']} episodes), validating on "
        f"{info['val_rows']} rows ({info['val_episodes']} episodes); {info['steps']} steps"
        + (f", resuming at step {info['resumed_at_step']}" if info["resumed_at_step"] else "")
    )
    finished = trainer.run()
    summary = {
        **info,
        "finished": finished,
        "state": asdict(trainer.state),
        "last": trainer.records[-1] if trainer.records else None,
    }
    write_atomic(out / "summary.json", json.dumps(summary, indent=2) + "\n")
    where = out / CHECKPOINT
    if finished:
        print(
            f"done: model in {where} (load it with --policy.model {where}); metrics in {out / 'metrics.jsonl'}"
        )
    else:
        print(
            f"stopped after --max-minutes at step {trainer.state.step} (checkpoint {where}); rerun the same command to continue"
        )
    return 0
