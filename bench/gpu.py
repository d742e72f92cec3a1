"""OpenVLA at its real size on a GPU: policy steps, all-layer capture, deferred observation, a LoRA step, probes.

On a CUDA device this builds the released OpenVLA-7B architecture (``openvla_7b()``: DINOv2-L + SigLIP-so400m,
Llama-2-7B, 33 hidden states of 4096) with seeded random weights in bf16, drawn on the GPU — random weights cost
what trained ones cost — and measures, each part in one run:

1. a policy step (LIBERO preprocessing, one prompt pass, six KV-cached decode steps, action decoding) without
   capture and with all 33 hidden states captured (``last_prompt``): median ms and their ratio; peak memory;
2. the deferred observation of stored episodes (``OpenVLAPolicy.steps``: batched prompt passes and decodes with
   capture, as ``vlaprobe collect`` runs it after an expert episode): images/s;
3. one LoRA fine-tune step with OpenVLA's recipe (rank 32 on every linear layer, AdamW lr 5e-4, batch 16,
   bf16 autocast; ``vlaprobe.finetune``'s objective): samples/s and peak memory;
4. the 66 probes (33 layers x 2 heads) of a paper-scale store, 5 episodes x 10 tasks x 150 steps x 33 layers x
   4096 (synthetic, labels linearly encoded: ``probes.data.synthetic_data``), trained on the GPU at C = 1 and
   with the default C search: seconds; parity with the CPU solver on two layers (largest logit difference and
   both balanced accuracies on the held-out episodes).

On a CPU the same code runs on the tiny configuration (``tiny_config``, fp32) and a store of 2 x 10 x 40 steps
of width 64; the JSON says ``"config": "tiny"``. A part that fails is reported in ``errors`` and the others still
run. Progress goes to stderr, one JSON line to stdout last.
"""

from __future__ import annotations

import json
import statistics
import sys
import time
import traceback
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
import torch

from vlaprobe.configs.train import ProbeConfig
from vlaprobe.policies.openvla import checkpoint
from vlaprobe.policies.openvla.config import OpenVLAConfig, openvla_7b
from vlaprobe.policies.openvla.model import ACTION_DIM
from vlaprobe.policies.openvla.policy import OpenVLAPolicy, device_and_dtype
from vlaprobe.policies.openvla.tiny import LIBERO_SPATIAL_LIKE_STATS, tiny_config, tiny_state_dict
from vlaprobe.policies.openvla.tokenizer import ACTION_ID_RANGE, WordHashTokenizer, prompt_ids

INSTRUCTION = "pick up the black bowl between the plate and the ramekin and place it on the plate"
SEED = 0
GiB = 2**30


@dataclass
class Size:
    """What one run measures: the model and the store's shape, and how many repetitions."""

    config: str
    """"openvla-7b" on CUDA, "tiny" on the CPU."""
    step_rounds: int
    """Timed policy steps per variant (interleaved plain / capture)."""
    observe_images: int
    """Images in the deferred observation."""
    lora_batch: int
    """Samples per LoRA step (OpenVLA's recipe: 16)."""
    lora_steps: int
    """Timed LoRA steps after one warm-up step."""
    episodes_per_task: int
    """The probe store: episodes per task (10 tasks)."""
    steps_per_episode: int
    """The probe store: steps per episode."""
    hidden: int
    """The probe store's width (the model's hidden size)."""


GPU = Size("openvla-7b", 20, 64, 16, 5, 5, 150, 4096)
CPU = Size("tiny", 3, 8, 2, 1, 2, 40, 64)


def log(msg: str) -> None:
    print(msg, file=sys.stderr, flush=True)


def timed(fn: Callable[[], object], device: torch.device) -> float:
    """Seconds of one call, the device's queue drained before and after."""
    if device.type == "cuda":
        torch.cuda.synchronize(device)
    start = time.perf_counter()
    fn()
    if device.type == "cuda":
        torch.cuda.synchronize(device)
    return time.perf_counter() - start


def peak_gib(device: torch.device) -> float | None:
    return round(torch.cuda.max_memory_allocated(device) / GiB, 2) if device.type == "cuda" else None


def reset_peak(device: torch.device) -> None:
    if device.type == "cuda":
        torch.cuda.reset_peak_memory_stats(device)


def build_policy(cfg: OpenVLAConfig, size: Size, device: torch.device, dtype: torch.dtype) -> OpenVLAPolicy:
    """The architecture with seeded random weights drawn on ``device`` in ``dtype``."""
    model = checkpoint.build_model(cfg, tiny_state_dict(cfg, SEED, device, dtype), device, dtype)
    return OpenVLAPolicy(
        model, WordHashTokenizer(), LIBERO_SPATIAL_LIKE_STATS, model_id=f"{size.config}-random-seed{SEED}"
    )


def frames(n: int, seed: int) -> np.ndarray:
    """``n`` agentview-sized (256 x 256) uint8 frames of seeded noise over a gradient."""
    rng = np.random.default_rng(seed)
    y, x = np.mgrid[0:256, 0:256]
    base = np.stack([x, y, (x + y) // 2], axis=-1)
    return ((base[None] + rng.integers(0, 64, (n, 256, 256, 3))) % 256).astype(np.uint8)


def bench_steps(policy: OpenVLAPolicy, size: Size) -> dict[str, object]:
    """Part 1: a policy step without and with the capture of every layer, interleaved."""
    from vlaprobe.policies.openvla import actions

    frame, device = frames(1, 1)[0], policy.device

    def plain() -> None:
        pred = policy.predict(policy.model_image(frame), policy.prompt_ids(INSTRUCTION), pooling=None)
        actions.libero_gripper(policy.decode(pred.action_token_ids.cpu().numpy()))

    def capture() -> None:
        policy.step(frame, INSTRUCTION)

    reset_peak(device)
    for fn in (plain, capture, plain, capture):  # warm-up: kernels, the prompt cache
        fn()
    times: dict[str, list[float]] = {"plain": [], "capture": []}
    for _ in range(size.step_rounds):
        times["plain"].append(timed(plain, device))
        times["capture"].append(timed(capture, device))
    ms = {k: statistics.median(v) * 1000 for k, v in times.items()}
    hidden = policy.step(frame, INSTRUCTION).hidden
    return {
        "ms_step_plain": round(ms["plain"], 2),
        "ms_step_capture": round(ms["capture"], 2),
        "capture_ratio": round(ms["capture"] / ms["plain"], 4),
        "hidden_shape": list(hidden.shape),
        "hidden_finite": bool(np.isfinite(hidden).all()),
        "peak_gib_step": peak_gib(device),
    }


def bench_observe(policy: OpenVLAPolicy, size: Size) -> dict[str, object]:
    """Part 2: deferred observation of stored frames (batched steps with capture)."""
    images = np.stack([policy.model_image(f) for f in frames(size.observe_images, 2)])
    policy.steps(images[:2], INSTRUCTION)  # warm-up
    reset_peak(policy.device)
    seconds = timed(lambda: policy.steps(images, INSTRUCTION), policy.device)
    return {
        "observe_images": len(images),
        "observe_images_per_s": round(len(images) / seconds, 2),
        "peak_gib_observe": peak_gib(policy.device),
    }


def bench_lora(policy: OpenVLAPolicy, size: Size) -> dict[str, object]:
    """Part 3: LoRA steps with OpenVLA's recipe through vlaprobe.finetune's objective (adapts the model in place)."""
    from vlaprobe.finetune.evaluate import autocast
    from vlaprobe.finetune.lora import add_lora
    from vlaprobe.finetune.objective import Batch, pixel_batch, sequences, step_forward

    model, device, cfg = policy.model, policy.device, policy.model.config
    add_lora(model, rank=32, dropout=0.0, seed=SEED)
    model.train()
    params = [p for p in model.parameters() if p.requires_grad]
    optimizer = torch.optim.AdamW(params, lr=5e-4, fused=device.type == "cuda")
    rng = np.random.default_rng(3)
    images = np.stack([policy.model_image(f) for f in frames(size.lora_batch, 3)])
    tokens = rng.integers(ACTION_ID_RANGE[0], ACTION_ID_RANGE[1], (size.lora_batch, ACTION_DIM))
    prompt = prompt_ids(policy.tokenizer, INSTRUCTION)
    ids, positions, labels = sequences([prompt] * size.lora_batch, tokens, cfg)
    batch = Batch(
        pixel_batch(images, cfg, device), False, ids.to(device), positions.to(device), labels.to(device)
    )
    forward = step_forward(model)
    losses: list[float] = []

    def step() -> None:
        with autocast(device, True):
            _, loss = forward(batch)
        optimizer.zero_grad(set_to_none=True)
        loss.backward()
        optimizer.step()
        losses.append(float(loss.detach()))

    timed(step, device)  # warm-up (optimizer state, kernels)
    reset_peak(device)
    seconds = [timed(step, device) for _ in range(size.lora_steps)]
    model.eval()
    return {
        "lora_trainable_parameters": sum(p.numel() for p in params),
        "lora_batch": size.lora_batch,
        "lora_samples_per_s": round(size.lora_batch / statistics.median(seconds), 2),
        "lora_ms_per_step": round(statistics.median(seconds) * 1000, 1),
        "lora_losses": [round(x, 4) for x in losses],
        "peak_gib_lora": peak_gib(device),
    }


def bench_probes(size: Size, device: torch.device) -> dict[str, object]:
    """Part 4: the 66 probes of a paper-scale store on ``device``; parity with the CPU solver on two layers."""
    from vlaprobe.probes.data import synthetic_data
    from vlaprobe.probes.evaluate import column_groups
    from vlaprobe.probes.metrics import confusion_by_group, metrics_from_counts
    from vlaprobe.probes.split import filter_labels, rows_of, split_episodes
    from vlaprobe.probes.trainer import fit_probes
    from vlaprobe.symbols import HEADS

    start = time.perf_counter()
    data = synthetic_data(
        num_tasks=10, episodes_per_task=size.episodes_per_task, steps_per_episode=size.steps_per_episode,
        num_layers=33, hidden_size=size.hidden, num_object=224, num_action=12, constant_fraction=0.55, seed=0,
    )  # fmt: skip
    made = time.perf_counter() - start
    fold = split_episodes(data.episode_tasks, test_fraction=0.2, folds=1, seed=0)[0]
    train, test = rows_of(data.episode, fold.train), rows_of(data.episode, fold.test)
    y = np.concatenate([data.labels[h] for h in HEADS], 1)
    head = np.repeat(np.arange(len(HEADS)), [data.labels[h].shape[1] for h in HEADS])
    keep = filter_labels(y[train], [str(i) for i in range(y.shape[1])], 0.01, 0.99).kept
    y, head = y[:, keep], head[keep]
    cfg = ProbeConfig(device=str(device))
    log(f"probes: store {data.num_steps} steps x 33 x {size.hidden} made in {made:.1f}s; {y.shape[1]} atoms")
    probes = None

    def fit_c1() -> None:
        nonlocal probes
        probes = fit_probes(data.hidden, y, train, cfg, seed=0, c=1.0)

    seconds_c1 = timed(fit_c1, device)
    groups = column_groups(data, head, 0)
    seconds_cv = timed(lambda: fit_probes(data.hidden, y, train, cfg, seed=0, groups=groups), device)
    assert probes is not None and probes.convergence is not None
    layers = [8, 24]
    cpu = fit_probes(data.hidden[layers], y, train, ProbeConfig(device="cpu"), seed=0, c=1.0)
    ours = probes.logits(data.hidden, test).numpy()[layers]
    ref = cpu.logits(data.hidden[layers], test).numpy()
    truth, one = y[test], np.zeros(len(test), int)

    def balanced(logits: np.ndarray) -> list[float]:  # per layer, mean over the atoms where it is defined
        counts = confusion_by_group(logits > 0, truth, one, 1)[0]
        return [round(float(np.nanmean(b)), 4) for b in metrics_from_counts(counts)["balanced_accuracy"]]

    return {
        "probe_store": [10 * size.episodes_per_task, size.steps_per_episode, 33, size.hidden],
        "probe_atoms": int(y.shape[1]),
        "probe_train_rows": len(train),
        "probe_seconds_c1": round(seconds_c1, 2),
        "probe_seconds_c_search": round(seconds_cv, 2),
        "probe_at_cap": int((~probes.convergence.converged).sum()),
        "parity_layers": layers,
        "parity_max_logit_diff": float(np.abs(ours - ref).max()),
        "parity_balanced_accuracy": balanced(ours),
        "parity_balanced_accuracy_cpu": balanced(ref),
    }


def main() -> int:
    device, dtype = device_and_dtype("auto")
    size = GPU if device.type == "cuda" else CPU
    cfg = openvla_7b() if device.type == "cuda" else tiny_config()
    result: dict[str, object] = {
        "bench": "gpu",
        "device": str(device),
        "config": size.config,
        "dtype": str(dtype),
    }
    if device.type == "cuda":
        result["gpu"] = torch.cuda.get_device_name(device)
    else:
        log("no CUDA device: the tiny configuration on the CPU (the same code, not OpenVLA-7B's figures)")
    result["torch"] = torch.__version__
    errors: dict[str, str] = {}
    start = time.perf_counter()
    policy = build_policy(cfg, size, device, dtype)
    result["build_s"] = round(time.perf_counter() - start, 1)
    result["parameters"] = sum(p.numel() for p in policy.model.parameters())
    result["peak_gib_weights"] = peak_gib(device)
    log(f"built {size.config}: {result['parameters']:,} parameters in {result['build_s']}s")
    parts: list[tuple[str, Callable[[OpenVLAPolicy, Size], dict[str, object]]]] = [
        ("steps", bench_steps),
        ("observe", bench_observe),
        ("lora", bench_lora),  # last: it adapts the model in place
    ]
    for name, part in parts:
        try:
            result |= part(policy, size)
            log(f"{name}: done")
        except Exception as exc:  # a failed part is reported and the others still run
            errors[name] = f"{type(exc).__name__}: {exc}"
            traceback.print_exc(file=sys.stderr)
    del policy
    if device.type == "cuda":
        torch.cuda.empty_cache()
    try:
        result |= bench_probes(size, device)
    except Exception as exc:
        errors["probes"] = f"{type(exc).__name__}: {exc}"
        traceback.print_exc(file=sys.stderr)
    result["errors"] = errors
    result["seconds"] = round(time.perf_counter() - start, 1)
    print(json.dumps(result))
    return 1 if errors else 0


if __name__ == "__main__":
    sys.exit(main())
