"""Success rate of the scripted expert on a LIBERO suite (spatial target: >= 95% over 10 tasks x 50 init states;
object and goal: >= 90% over init states 0-9 of every task).

Each episode: reset to a fixed init state (settled), then at most 300 expert steps, stopping at LIBERO's own
success check. Runs without rendering, one env per task, tasks spread over worker processes. Prints one line
per task on stderr and the figures as a final JSON line on stdout.

    python bench/expert_success.py              # LIBERO-spatial, 10 tasks x 5 init states (~2 min on 2 cores)
    python bench/expert_success.py --suite libero_goal --inits 10   # another suite
    python bench/expert_success.py --inits 15   # first 15 init states of every task
    python bench/expert_success.py --all        # all 50 init states (~20 min on 2 cores)
    python bench/expert_success.py --suite libero_90 --tasks 0-32,34,36-89 --max-steps 520
                                                # tasks whose goal no skill handles are skipped (named)
"""

from __future__ import annotations

import argparse
import json
import multiprocessing as mp
import os
import sys
import time
from pathlib import Path

from quick import size
from vlaprobe.configs.env import SUITES

MAX_STEPS = size(300, 20)  # episode budget after settling (LiberoTaskEnv's default max_steps)


def run_task(job: tuple[str, int, list[int], int, int]) -> list[dict]:
    """Run the expert on one task's init states; one record per episode."""
    suite, task, inits, seed, max_steps = job
    import numpy as np

    from vlaprobe.configs.env import EnvConfig
    from vlaprobe.envs.libero import LiberoTaskEnv
    from vlaprobe.experts import ScriptedExpert

    records = []
    with LiberoTaskEnv(task, EnvConfig(suite=suite, render=False)) as env:  # type: ignore[arg-type]
        expert = ScriptedExpert(env, seed=seed)
        for init in inits:
            # LIBERO's soft reset samples object placements from numpy's global generator before the init state
            # overwrites them; seeding it makes an episode repeatable (given the same preceding episodes).
            np.random.seed(1000 * task + init)
            start = time.process_time()
            obs = env.reset(init)
            expert.reset()
            steps = 0
            while steps < max_steps and not obs.success:
                obs = env.step(expert.act())
                steps += 1
            records.append(
                {
                    "task": task,
                    "init": init,
                    "success": bool(obs.success),
                    "steps": steps,
                    "phase": expert.phase,
                    "cpu_s": time.process_time() - start,
                }
            )
    return records


def parse_tasks(text: str) -> list[int]:
    """Task indices from "0-9", "2,4" or a mix ("0-32,34,36-89")."""
    tasks: list[int] = []
    for part in text.split(","):
        first, _, last = part.partition("-")
        tasks += range(int(first), int(last or first) + 1)
    return tasks


def no_skill(suite: str, tasks: list[int]) -> dict[int, str]:
    """The tasks whose goal no expert skill handles -> that conjunct (as ``vlaprobe collect`` refuses them)."""
    from vlaprobe.configs.env import EnvConfig
    from vlaprobe.experts.planner import unplannable_tasks

    return unplannable_tasks(EnvConfig(suite=suite), tuple(tasks))  # type: ignore[arg-type]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--suite", default="libero_spatial", choices=SUITES, help="LIBERO suite")
    parser.add_argument("--inits", type=int, default=size(5, 1), help="first N init states of every task")
    parser.add_argument("--all", action="store_true", help="all init states (50 per task)")
    parser.add_argument("--first-init", type=int, default=0, help="first init state (then --inits of them)")
    parser.add_argument("--tasks", type=str, default=size("0-9", "0"), help="task indices, e.g. 0-9 or 2,4")
    parser.add_argument("--procs", type=int, default=size(2, 1), help="worker processes (one env each)")
    parser.add_argument("--seed", type=int, default=0, help="expert seed")
    parser.add_argument("--max-steps", type=int, default=MAX_STEPS, help="episode budget (libero_10: 520)")
    args = parser.parse_args()

    os.environ.setdefault("OMP_NUM_THREADS", "1")
    # Offline machines: use the shared assets folder beside the checkout when none is named (as the tests do).
    shared_assets = Path(__file__).resolve().parents[2] / "shared" / "libero_assets"
    if "VLAPROBE_LIBERO_ASSETS" not in os.environ and shared_assets.is_dir():
        os.environ["VLAPROBE_LIBERO_ASSETS"] = str(shared_assets)
    tasks = parse_tasks(args.tasks)
    skipped = no_skill(args.suite, tasks)
    for task, conjunct in skipped.items():
        print(f"task {task}: skipped (no skill for {conjunct})", file=sys.stderr, flush=True)
    tasks = [t for t in tasks if t not in skipped]
    inits = list(range(50)) if args.all else list(range(args.first_init, args.first_init + args.inits))
    jobs = [(args.suite, task, inits, args.seed, args.max_steps) for task in tasks]

    wall = time.perf_counter()
    records: list[dict] = []
    with mp.get_context("spawn").Pool(min(args.procs, len(jobs))) as pool:
        for task_records in pool.imap_unordered(run_task, jobs):
            records.extend(task_records)
            task = task_records[0]["task"]
            ok = sum(r["success"] for r in task_records)
            failed = [(r["init"], r["phase"]) for r in task_records if not r["success"]]
            print(f"task {task}: {ok}/{len(task_records)} failed={failed}", file=sys.stderr, flush=True)

    records.sort(key=lambda r: (r["task"], r["init"]))
    per_task = {
        str(t): round(sum(r["success"] for r in records if r["task"] == t) / len(inits), 4) for t in tasks
    }
    successes = [r for r in records if r["success"]]
    result = {
        "success_rate": round(len(successes) / len(records), 4),
        "episodes": len(records),
        "per_task": per_task,
        "mean_steps_success": round(sum(r["steps"] for r in successes) / max(len(successes), 1), 1),
        "max_steps_success": max((r["steps"] for r in successes), default=0),
        "cpu_s_per_episode": round(sum(r["cpu_s"] for r in records) / len(records), 2),
        "wall_s": round(time.perf_counter() - wall, 1),
        "failures": [[r["task"], r["init"], r["phase"]] for r in records if not r["success"]],
        "skipped": {str(t): c for t, c in skipped.items()},
        "steps": [[r["task"], r["init"], r["steps"]] for r in records if r["success"]],
        "suite": args.suite,
        "max_steps": args.max_steps,
        "target": 0.95 if args.suite == "libero_spatial" else 0.9,
    }
    print(json.dumps(result))


if __name__ == "__main__":
    main()
