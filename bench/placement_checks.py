"""Sampled layouts: how many draws the checks reject and why, and whether they pass the layouts LIBERO ships.

For ``--inits sampled`` and ``--inits sampled-swap``: sample indices 0-29 of every LIBERO-spatial task (300
resets each, no episode), the draws made, the share rejected with its 95% Wilson interval, and every rejected
draw's reasons, counted per reason (an object's name and the numbers left out). Then LIBERO's own fixed init states (tasks 0-9 x 50), settled as ``--inits fixed``
settles them, through the same checks: LIBERO ships these layouts, so a check that rejects one is stricter than
LIBERO's own standard (``vlaprobe.envs.placements``). Final line: JSON.

    python bench/placement_checks.py       # ~15 minutes on a free 2-core machine
"""

from __future__ import annotations

import collections
import json
import math
import re
import sys

from quick import size

SAMPLES = size(30, 1)
"""Sample indices per task. 10 (100 resets) left the rate's 95% interval ~±5 points wide around a 5% target."""
FIXED = size(50, 1)
TASKS = size(10, 1)


def wilson(k: int, n: int, z: float = 1.96) -> tuple[float, float]:
    """95% Wilson score interval of a proportion k / n."""
    p, d = k / n, 1 + z * z / n
    half = z * math.sqrt(p * (1 - p) / n + z * z / (4 * n * n)) / d
    return (p + z * z / (2 * n)) / d - half, (p + z * z / (2 * n)) / d + half


def _reason(text: str) -> str:
    return re.sub(r"_\d+\b|\(.*?\)|[0-9.]+", "", text).strip()


def main() -> None:
    from vlaprobe.configs.env import EnvConfig
    from vlaprobe.envs.libero import LiberoTaskEnv

    out: dict[str, object] = {}
    for inits in ("sampled", "sampled-swap"):
        draws, rejected, reasons = 0, 0, collections.Counter()
        for task in range(TASKS):
            with LiberoTaskEnv(task, EnvConfig(render=False, inits=inits)) as env:  # type: ignore[arg-type]
                for i in range(SAMPLES):
                    env.reset(i)
                    p = env.last_placement
                    assert p is not None
                    draws, rejected = draws + p.draws, rejected + len(p.rejected)
                    reasons.update(_reason(part) for r in p.rejected for part in r.split("; "))
                    print(
                        f"{inits} task {task} sample {i}: {p.draws} draws, {list(p.rejected)}",
                        file=sys.stderr,
                    )
        low, high = wilson(rejected, draws)
        out[inits] = {"resets": TASKS * SAMPLES, "draws": draws, "rejected": rejected, "rate": rejected / draws,
                      "rate_95": [round(low, 4), round(high, 4)], "reasons": dict(reasons.most_common())}  # fmt: skip
    failed, reasons = [], collections.Counter()
    for task in range(TASKS):
        with LiberoTaskEnv(task, EnvConfig(render=False)) as env:
            for i in range(FIXED):
                problems = env.fixed_layout_problems(i)
                if problems:
                    failed.append({"task": task, "init": i, "problems": problems})
                    reasons.update(_reason(p) for p in problems)
    out["libero_fixed_inits"] = {"layouts": TASKS * FIXED, "rejected": len(failed), "failed": failed,
                                 "reasons": dict(reasons.most_common())}  # fmt: skip
    print(json.dumps(out))


if __name__ == "__main__":
    main()
