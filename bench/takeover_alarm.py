"""The live alarm's cost per step (``--takeover alarm``): the alarm rule on the cognition's conclusions.

Target: median <= 1 ms per step. The input is ``cognition_step.py``'s probe-like synthetic episode
(LIBERO-spatial's 236 atoms, 1-12 wrong per step) through the real cognition; timed apart: the cognition's step
(what the live server runs anyway) and the alarm rule on its output with the takeover request it makes
(:class:`vlaprobe.cognition.alarm.AlarmRule`, :meth:`vlaprobe.rollout.EpisodeControl.take_over`). Prints the
alarm's median and p99 per step and its ratio to the cognition's step; one JSON line at the end.

    python bench/takeover_alarm.py
"""

from __future__ import annotations

import json
import time

import numpy as np

from cognition_step import GOAL, SCENE, WARMUP, stream
from vlaprobe.cognition import Cognition
from vlaprobe.cognition.alarm import AlarmRule
from vlaprobe.rollout import EpisodeControl
from vlaprobe.symbols import build_vocabulary


def main() -> None:
    vocab = build_vocabulary(SCENE)
    steps = stream(vocab)
    cog = Cognition(vocab.object_atoms, vocab.action_atoms, GOAL)
    rule, control = AlarmRule(stall=40, hold=5, most=10**9), EpisodeControl()
    cognition_ms, alarm_ms, fired = [], [], 0
    for i, (obj, act) in enumerate(steps):
        t0 = time.perf_counter()
        c = cog.step(obj, act)
        t1 = time.perf_counter()
        alarm = rule.check(c, acting=False)
        if alarm is not None:
            control.take_over(f"{alarm.kind}: {alarm.reason}")
            control.take_takeover()
        t2 = time.perf_counter()
        if i >= WARMUP:
            cognition_ms.append((t1 - t0) * 1e3)
            alarm_ms.append((t2 - t1) * 1e3)
            fired += alarm is not None
    median = float(np.median(alarm_ms))
    result = {
        "bench": "takeover_alarm",
        "steps": len(alarm_ms),
        "alarms": fired,
        "alarm_ms_median": round(median, 4),
        "alarm_ms_p99": round(float(np.percentile(alarm_ms, 99)), 4),
        "cognition_ms_median": round(float(np.median(cognition_ms)), 4),
        "alarm_to_cognition": round(median / float(np.median(cognition_ms)), 4),
        "target_ms": 1.0,
        "meets_target": median <= 1.0,
    }
    print(
        f"alarm {median:.4f} ms per step (p99 {result['alarm_ms_p99']} ms), cognition {result['cognition_ms_median']} ms"
    )
    print(json.dumps(result))


if __name__ == "__main__":
    main()
