"""Training-step speed of ``vlaprobe finetune`` on the tiny OpenVLA, and how close it runs to this CPU's peak.

One step = pixel values of a batch of 16 224² images, both ViTs, the projector, the 32-layer decoder over
the whole sequence (256 patches + prompt + 7 action tokens), ``lm_head`` at the 8 labelled positions only,
cross-entropy, backward, gradient clipping and the AdamW update: exactly ``Trainer.step``'s work.

Timed interleaved, round after round, against (1) the same step with ``lm_head`` over every position (what a
plain ``LlamaForCausalLM`` forward with labels computes), (2) the step with frozen, cached featurisers
(``--freeze-vision``), (3) the step compiled with ``torch.compile`` (``--compile``; its one-off compile is
timed apart as ``compile_s``) and (4) a square float32 matmul whose rate is this CPU's matmul peak at the same
thread count, so a slow spell of the shared machine hits all of them alike. The step's FLOPs come from
torch's ``FlopCounterMode`` (matmuls, convolutions and attention, forward and backward); ``share_of_peak``
= achieved GFLOP/s ÷ matmul peak. One torch thread: on a shared machine OpenMP threads spin against the other
jobs (two threads ran ~4x slower than one on the loaded 2-core box). Prints a final JSON line.
"""

from __future__ import annotations

import json
import statistics
import time
from collections.abc import Callable

import numpy as np
import torch

from quick import QUICK, size

THREADS = 1
BATCH = size(16, 2)
ROUNDS = size(3, 1)
MATMUL = size(768, 64)


def _interleaved(fns: dict[str, Callable[[], object]], rounds: int) -> dict[str, float]:
    """Median seconds of each function, timed round-robin after one warm-up call each."""
    for fn in fns.values():
        fn()
    times: dict[str, list[float]] = {name: [] for name in fns}
    for _ in range(rounds):
        for name, fn in fns.items():
            start = time.perf_counter()
            fn()
            times[name].append(time.perf_counter() - start)
    return {name: statistics.median(t) for name, t in times.items()}


def _examples(model: torch.nn.Module, rows: int):
    from vlaprobe.finetune.data import Demonstrations, EpisodeRef
    from vlaprobe.finetune.examples import ActionStats, make_examples
    from vlaprobe.policies.openvla.tokenizer import WordHashTokenizer

    rng = np.random.default_rng(0)
    size = model.config.featurizer.image_size
    demos = Demonstrations(
        images=rng.integers(0, 256, (rows, size, size, 3), dtype=np.uint8),
        actions=np.concatenate([rng.uniform(-1, 1, (rows, 6)), rng.integers(0, 2, (rows, 1))], axis=1),
        proprio=None,
        episode=np.zeros(rows, dtype=np.int64),
        episodes=[
            EpisodeRef(
                0, "t00_i00_a00", 0, "pick up the black bowl next to the ramekin and place it on the plate"
            )
        ],
    )
    stats = ActionStats(-np.ones(7), np.ones(7), np.array([True] * 6 + [False]))
    return make_examples(demos, WordHashTokenizer(), stats, model)


def _step_fn(
    model, examples, rows: np.ndarray, full_logits: bool = False, compiled: bool = False
) -> Callable[[], float]:
    from vlaprobe.finetune.examples import make_batch
    from vlaprobe.finetune.objective import loss_of, step_forward

    forward = step_forward(model, compile=compiled)

    params = [p for p in model.parameters() if p.requires_grad]
    optimizer = torch.optim.AdamW(params, lr=1e-4, fused=True)
    device = torch.device("cpu")

    def logits_everywhere(batch):  # lm_head over the whole sequence, then the labelled positions
        embeds = (
            model.embed_features(batch.inputs, batch.input_ids)
            if batch.features
            else model.embed(batch.inputs, batch.input_ids)
        )
        hidden = model.language_model.model(inputs_embeds=embeds, use_cache=False).last_hidden_state
        logits = model.language_model.lm_head(hidden)
        return logits.gather(1, batch.positions.unsqueeze(-1).expand(-1, -1, logits.shape[-1]))

    def step() -> float:
        batch = make_batch(examples, rows, model, device)
        loss = loss_of(logits_everywhere(batch), batch.labels) if full_logits else forward(batch)[1]
        optimizer.zero_grad(set_to_none=True)
        loss.backward()
        torch.nn.utils.clip_grad_norm_(params, 1.0)
        optimizer.step()
        return float(loss.detach())

    return step


def _flops(step: Callable[[], float]) -> float:
    from torch.utils.flop_counter import FlopCounterMode

    with FlopCounterMode(display=False) as counter:
        step()
    return float(counter.get_total_flops())


def main() -> None:
    torch.set_num_threads(THREADS)
    from vlaprobe.finetune.examples import cache_features, longest_sequence
    from vlaprobe.policies.openvla.policy import OpenVLAPolicy

    model = OpenVLAPolicy.tiny(seed=0, device="cpu").model.train()
    examples = _examples(model, BATCH)
    rows = np.arange(BATCH)
    full = _step_fn(model, examples, rows)
    full_logits = _step_fn(model, examples, rows, full_logits=True)
    frozen_model = OpenVLAPolicy.tiny(seed=0, device="cpu").model.train()
    frozen_model.vision_backbone.requires_grad_(False)
    frozen_examples = _examples(frozen_model, BATCH)
    cache_features(frozen_examples, frozen_model, torch.device("cpu"))
    frozen = _step_fn(frozen_model, frozen_examples, rows)
    compiled_model = OpenVLAPolicy.tiny(seed=0, device="cpu").model.train()
    compiled_examples = _examples(compiled_model, BATCH)
    compiled_examples.width = longest_sequence(compiled_examples)
    compiled = _step_fn(compiled_model, compiled_examples, rows, compiled=not QUICK)  # quick: no C++ build
    start = time.perf_counter()
    compiled()  # the one-off compile (inductor writes and builds C++ kernels)
    compile_s = time.perf_counter() - start
    a, b = torch.randn(MATMUL, MATMUL), torch.randn(MATMUL, MATMUL)

    def matmul() -> None:
        for _ in range(8):
            torch.mm(a, b)

    flops = _flops(full)
    fns = {"step": full, "full_logits": full_logits, "frozen": frozen, "compiled": compiled, "matmul": matmul}
    t = _interleaved(fns, ROUNDS)
    peak = 8 * 2 * MATMUL**3 / t["matmul"] / 1e9
    achieved = flops / t["step"] / 1e9
    result = {
        "threads": THREADS,
        "batch": BATCH,
        "samples_per_s": round(BATCH / t["step"], 2),
        "ms_per_sample": round(1000 * t["step"] / BATCH, 1),
        "gflop_per_sample": round(flops / BATCH / 1e9, 3),
        "achieved_gflop_s": round(achieved, 2),
        "matmul_peak_gflop_s": round(peak, 2),
        "share_of_peak": round(achieved / peak, 3),
        "ms_per_sample_full_logits": round(1000 * t["full_logits"] / BATCH, 1),
        "full_logits_over_step": round(t["full_logits"] / t["step"], 2),
        "ms_per_sample_frozen_vision": round(1000 * t["frozen"] / BATCH, 1),
        "ms_per_sample_compiled": round(1000 * t["compiled"] / BATCH, 1),
        "compiled_speedup": round(t["step"] / t["compiled"], 2),
        "compile_s": round(compile_s, 1),
    }
    print(json.dumps(result))


if __name__ == "__main__":
    main()
