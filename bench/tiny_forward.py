"""Milliseconds per policy step of the tiny default OpenVLA on this CPU, and where they go.

One step = LIBERO preprocessing of a 256×256 frame (rotate, JPEG round trip, lanczos resize, centre crop),
the vision backbone and projector, the prompt pass (256 patches + ~32 text tokens through 32 decoder layers,
all hidden states captured), six KV-cached decode steps and the action decoding. Runs on one torch thread
(the machine is shared). ``ms_*`` are medians of wall time; ``cpu_ms_per_step`` is this process's CPU time
per step, the cost on an idle core. The phases are timed interleaved, round after round, so a slow spell of
the machine hits all of them alike.

``ms_jpeg`` is the JPEG round trip inside the preprocessing (Pillow's encoder + simplejpeg's fast-IDCT
decoder, bit-exact with TensorFlow; measured 0.3 ms here, against 5.9 ms for the integer numpy
re-implementation it replaced).

``decode_speedup`` compares, in the same run, our six decode steps (``vlaprobe.policies.openvla.decode``)
with the same six steps through transformers' ``LlamaModel.forward`` and its ``DynamicCache``.
Prints the breakdown and a final JSON line.
"""

from __future__ import annotations

import copy
import json
import statistics
import time
from collections.abc import Callable

import numpy as np
import torch

from quick import size

ROUNDS = size(20, 2)
INSTRUCTION = "pick up the black bowl between the plate and the ramekin and place it on the plate"


def _interleaved(
    fns: dict[str, Callable[[], object]], rounds: int, clock=time.perf_counter
) -> dict[str, float]:
    """Median milliseconds of each function, timed round-robin after one warm-up call each."""
    for fn in fns.values():
        fn()
    times: dict[str, list[float]] = {name: [] for name in fns}
    for _ in range(rounds):
        for name, fn in fns.items():
            start = clock()
            fn()
            times[name].append((clock() - start) * 1000)
    return {name: round(statistics.median(t), 1) for name, t in times.items()}


def main() -> None:
    torch.set_num_threads(1)
    from vlaprobe.policies.openvla.decode import CachedDecoder
    from vlaprobe.policies.openvla.jpeg import jpeg_round_trip
    from vlaprobe.policies.openvla.model import ACTION_DIM
    from vlaprobe.policies.openvla.policy import OpenVLAPolicy

    start = time.perf_counter()
    policy = OpenVLAPolicy.tiny(seed=0, device="cpu")
    build_ms = (time.perf_counter() - start) * 1000
    y, x = np.mgrid[0:256, 0:256]
    frame = np.stack([x, y, (x + y) // 2], axis=-1).astype(np.uint8)

    model, lm = policy.model, policy.model.language_model
    image = policy.model_image(frame)
    ids = policy.prompt_ids(INSTRUCTION)
    pixels = policy.pixel_values(image)
    steps = ACTION_DIM - 1
    with torch.inference_mode():
        embeds = model.embed(pixels, ids)
        prompt = lm.model(inputs_embeds=embeds, use_cache=True)
    token = torch.tensor([model.config.action_vocab_end - 1])

    @torch.inference_mode()
    def ours() -> None:
        decoder = CachedDecoder(lm, prompt.past_key_values, embeds.shape[1], steps, record=False)
        for _ in range(steps):
            decoder.step(token)

    # transformers' cache grows in place: each timed call gets its own copy of the prompt's, made beforehand.
    spare_caches = [copy.deepcopy(prompt.past_key_values) for _ in range(ROUNDS + 1)]

    @torch.inference_mode()
    def transformers_decode() -> None:
        cache = spare_caches.pop()
        for _ in range(steps):
            out = lm.model(input_ids=token[:, None], past_key_values=cache, use_cache=True)
            cache = out.past_key_values
            lm.lm_head(out.last_hidden_state[:, -1])

    @torch.inference_mode()
    def prompt_pass() -> None:
        lm.model(inputs_embeds=embeds, use_cache=True, output_hidden_states=True)

    @torch.inference_mode()
    def vision() -> None:
        model.embed(pixels, ids)

    wall = _interleaved(
        {
            "step": lambda: policy.step(frame, INSTRUCTION),
            "preprocess": lambda: policy.model_image(frame),
            "jpeg": lambda: jpeg_round_trip(frame),
            "network": lambda: policy.predict(image, ids, "last_prompt"),
            "vision": vision,
            "prompt_pass": prompt_pass,
            "decode": ours,
            "decode_transformers": transformers_decode,
        },
        ROUNDS,
    )
    cpu = _interleaved({"step": lambda: policy.step(frame, INSTRUCTION)}, ROUNDS, clock=time.process_time)
    result = {
        "bench": "tiny_forward",
        "ms_per_step": wall["step"],
        "cpu_ms_per_step": cpu["step"],
        "ms_preprocess": wall["preprocess"],
        "ms_jpeg": wall["jpeg"],
        "ms_network": wall["network"],
        "ms_vision": wall["vision"],
        "ms_prompt_pass": wall["prompt_pass"],
        "ms_decode": wall["decode"],
        "ms_decode_transformers": wall["decode_transformers"],
        "decode_speedup": round(wall["decode_transformers"] / wall["decode"], 2),
        "ms_build": round(build_ms),
        "rounds": ROUNDS,
        "threads": torch.get_num_threads(),
        "hidden_size": policy.hidden_size,
        "num_hidden_states": policy.num_hidden_states,
        "sequence_length": int(ids.shape[1]) + 256,
        "num_parameters": policy.describe()["num_parameters"],
    }
    print(
        f"tiny OpenVLA step: {result['ms_per_step']} ms (CPU {result['cpu_ms_per_step']}): preprocess "
        f"{result['ms_preprocess']} (of which JPEG round trip {result['ms_jpeg']}), network {result['ms_network']} = vision {result['ms_vision']} + prompt pass "
        f"{result['ms_prompt_pass']} + 6 decode steps {result['ms_decode']} "
        f"(transformers' decode: {result['ms_decode_transformers']}, {result['decode_speedup']}× slower)"
    )
    print(json.dumps(result))


if __name__ == "__main__":
    main()
