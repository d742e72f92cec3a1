"""The policy check: the run's model loads, and one step is timed with and without the hidden-state capture."""

from __future__ import annotations

import time
from collections.abc import Callable

import numpy as np

from vlaprobe.configs.checks import check_policy
from vlaprobe.configs.doctor import DoctorConfig
from vlaprobe.doctor.report import Check
from vlaprobe.files import JsonObject
from vlaprobe.policies.factory import make_policy

INSTRUCTION = "pick up the black bowl between the plate and the ramekin and place it on the plate"
REPEATS = 2
"""Timed steps of each kind after one untimed step (the first step of a process pays one-off costs)."""


def synthetic_frame(size: int = 256) -> np.ndarray:
    """A smooth colour ramp, as ``vlaprobe model-info --step`` uses: what the model sees does not matter here."""
    y, x = np.mgrid[0:size, 0:size]
    return np.stack([x, y, (x + y) // 2], axis=-1).astype(np.uint8)


def policy_check(cfg: DoctorConfig) -> tuple[Check, tuple[int, int] | None]:
    """The check, and the model's (hidden states, hidden size) for the disk estimate (None: it did not load)."""
    from vlaprobe.policies.openvla.policy import OpenVLAPolicy

    check_policy(cfg.policy)
    start = time.perf_counter()
    policy = make_policy(cfg.policy)
    load = time.perf_counter() - start
    dims = (policy.num_hidden_states, policy.hidden_size)
    frame = synthetic_frame()
    step = policy.step(frame, INSTRUCTION)
    figures: JsonObject = {
        "model_id": policy.model_id,
        "load_seconds": round(load, 3),
        "hidden_shape": list(step.hidden.shape),
        "dtype": str(policy.describe()["dtype"]),
        "device": str(policy.describe()["device"]),
    }
    summary = f"{policy.model_id} loads in {load:.1f} s on {figures['device']} ({figures['dtype']})"
    if isinstance(policy, OpenVLAPolicy):
        image, ids = policy.model_image(frame), policy.prompt_ids(INSTRUCTION)
        plain = _best(lambda: policy.predict(image, ids, None))
        captured = _best(lambda: policy.predict(image, ids, policy.pooling))
        overhead = captured / plain - 1
        figures |= {
            "step_seconds": round(captured, 4),
            "step_seconds_no_capture": round(plain, 4),
            "capture_overhead": round(overhead, 3),
        }
        summary += (
            f"; a step takes {1000 * captured:.0f} ms with every layer's states captured, "
            f"{1000 * plain:.0f} ms without ({100 * overhead:+.0f}%); hidden {tuple(step.hidden.shape)}"
        )
    return Check("policy", "ok", summary, figures=figures), dims


def _best(step: Callable[[], object]) -> float:
    """The fastest of :data:`REPEATS` timed calls (the least disturbed by other processes)."""
    times = []
    for _ in range(REPEATS):
        start = time.perf_counter()
        step()
        times.append(time.perf_counter() - start)
    return min(times)
