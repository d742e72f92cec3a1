"""Time the ground-truth detectors: all 236 atoms of one world state (target: <= 1 ms).

Snapshots are taken from the real LIBERO-spatial env (task 4, the drawer task, whose scene exercises every
predicate) along a short random rollout; then the labeler runs over them many times. Also reports the cost of
taking a snapshot from the simulator. Prints a final JSON line.

    python bench/label_speed.py [--states 50] [--repeats 40]
"""

from __future__ import annotations

import argparse
import json
import time

import numpy as np

from quick import size
from vlaprobe.configs.env import EnvConfig
from vlaprobe.envs.libero import LiberoTaskEnv


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--states", type=int, default=size(50, 3), help="world states to snapshot")
    parser.add_argument(
        "--repeats", type=int, default=size(40, 2), help="passes of the labeler over all states"
    )
    args = parser.parse_args()

    rng = np.random.default_rng(0)
    with LiberoTaskEnv(4, EnvConfig(render=False)) as env:
        env.reset(0)
        states = []
        snap_times = []
        for _ in range(args.states):
            action = np.concatenate([rng.uniform(-0.5, 0.5, 6), [rng.choice([-1.0, 1.0])]])
            env.step(action)
            t0 = time.perf_counter()
            states.append(env.world_state())
            snap_times.append(time.perf_counter() - t0)
        labeler = env.labeler
        n_atoms = len(labeler.vocabulary.object_atoms) + len(labeler.vocabulary.action_atoms)
        for s in states:  # warm-up
            labeler(s)
        t0 = time.perf_counter()
        for _ in range(args.repeats):
            for s in states:
                labeler(s)
        per_state = (time.perf_counter() - t0) / (args.repeats * len(states))
    result = {
        "atoms": n_atoms,
        "label_ms_per_state": round(per_state * 1e3, 4),
        "snapshot_ms": round(float(np.median(snap_times)) * 1e3, 4),
        "target_ms": 1.0,
        "meets_target": per_state * 1e3 <= 1.0,
    }
    print(json.dumps(result))


if __name__ == "__main__":
    main()
