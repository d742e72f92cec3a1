"""Count the object atoms that vary across LIBERO's fixed init states (settled), per suite.

A probe can only be scored on atoms that take both values; the majority baseline is high where few vary. For each
suite the given tasks (default: the first of each suite) are reset to every fixed init state (50), and the atoms
whose value differs between two init states are counted, over the task's own vocabulary. Prints one line per
task, then a final JSON line.

    python bench/init_variation.py [--tasks 0] [--inits 50] [--suites libero_goal libero_10]
"""

from __future__ import annotations

import argparse
import json
import time

import numpy as np

from quick import size
from vlaprobe.configs.env import SUITES, EnvConfig
from vlaprobe.envs.libero import LiberoTaskEnv


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--suites", nargs="+", default=size(list(SUITES), ["libero_spatial"]), choices=SUITES)
    parser.add_argument("--tasks", nargs="+", type=int, default=[0], help="task indices of each suite")
    parser.add_argument("--inits", type=int, default=size(50, 2), help="init states per task (LIBERO has 50)")
    args = parser.parse_args()

    rows = []
    for suite in args.suites:
        for task in args.tasks:
            start = time.perf_counter()
            with LiberoTaskEnv(task, EnvConfig(suite=suite, render=False)) as env:
                bits = []
                for init in range(min(args.inits, env.num_init_states)):
                    env.reset(init)
                    bits.append(env.labels()[0])
                atoms = np.array(env.labeler.vocabulary.object_atoms)
            values = np.stack(bits)
            varying = values.any(axis=0) & ~values.all(axis=0)
            row = {
                "suite": suite,
                "task": task,
                "inits": len(bits),
                "object_atoms": int(values.shape[1]),
                "varying": int(varying.sum()),
                "always_true": int(values.all(axis=0).sum()),
                "varying_non_spatial": sorted(
                    a
                    for a in atoms[varying]
                    if a.split("(")[0] not in ("behind", "in-front-of", "left-of", "right-of")
                ),
                "seconds": round(time.perf_counter() - start, 1),
            }
            rows.append(row)
            print(
                f"{suite} task {task}: {row['varying']} of {row['object_atoms']} object atoms vary over "
                f"{row['inits']} init states ({row['always_true']} always true); non-spatial varying: "
                f"{', '.join(row['varying_non_spatial']) or 'none'} ({row['seconds']} s)",
                flush=True,
            )
    print(json.dumps(rows))


if __name__ == "__main__":
    main()
