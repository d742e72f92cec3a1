"""Cost of capturing every layer's hidden states: ratio = time(step with capture) / time(plain prediction).

Both run the same policy step on the tiny default OpenVLA (preprocessing, prompt pass, six KV-cached
decode steps, action decoding); "plain" only predicts the action, "capture" also returns all 33 hidden
states pooled. The capture comes from the same forward passes, so the ratio should stay near 1 (target
≤ 1.05). Runs are interleaved A/B/A/B so the shared machine's load hits both alike; medians compared.
"""

from __future__ import annotations

import json
import statistics
import time

import numpy as np
import torch

from quick import size

ROUNDS = size(30, 2)
INSTRUCTION = "pick up the black bowl between the plate and the ramekin and place it on the plate"


def main() -> None:
    torch.set_num_threads(1)
    from vlaprobe.policies.openvla import actions
    from vlaprobe.policies.openvla.policy import OpenVLAPolicy

    policy = OpenVLAPolicy.tiny(seed=0, device="cpu")
    y, x = np.mgrid[0:256, 0:256]
    frame = np.stack([x, y, (x + y) // 2], axis=-1).astype(np.uint8)

    def plain() -> None:
        image = policy.model_image(frame)
        pred = policy.predict(image, policy.prompt_ids(INSTRUCTION), pooling=None)
        actions.libero_gripper(policy.decode(pred.action_token_ids.numpy()))

    def capture(pooling: str) -> None:
        policy.pooling = pooling  # type: ignore[assignment]
        policy.step(frame, INSTRUCTION)

    variants = {
        "plain": plain,
        "last_prompt": lambda: capture("last_prompt"),
        "action_tokens": lambda: capture("action_tokens"),
    }
    for fn in variants.values():  # warm-up
        fn()
    times: dict[str, list[float]] = {name: [] for name in variants}
    for _ in range(ROUNDS):
        for name, fn in variants.items():
            start = time.perf_counter()
            fn()
            times[name].append(time.perf_counter() - start)
    med = {name: statistics.median(t) * 1000 for name, t in times.items()}
    result = {
        "bench": "capture_overhead",
        "ratio": round(med["last_prompt"] / med["plain"], 4),
        "ratio_action_tokens": round(med["action_tokens"] / med["plain"], 4),
        "ms_plain": round(med["plain"], 1),
        "ms_capture": round(med["last_prompt"], 1),
        "ms_capture_action_tokens": round(med["action_tokens"], 1),
        "rounds": ROUNDS,
        "threads": torch.get_num_threads(),
        "target": 1.05,
    }
    print(f"capture/plain = {result['ratio']} (action_tokens: {result['ratio_action_tokens']})")
    print(json.dumps(result))


if __name__ == "__main__":
    main()
