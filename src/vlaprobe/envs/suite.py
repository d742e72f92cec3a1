"""``vlaprobe tasks`` and ``vlaprobe atoms``: look at the suite and at the ground truth of a settled init state."""

from __future__ import annotations

import json

from vlaprobe.configs.suite import AtomsConfig, TasksConfig
from vlaprobe.envs import make_env
from vlaprobe.envs.libero import suite_tasks
from vlaprobe.symbols import HEADS


def tasks(cfg: TasksConfig) -> int:
    """Print the suite's tasks: index and instruction (needs no LIBERO assets)."""
    rows = suite_tasks(cfg.env.suite)
    if cfg.json:
        print(json.dumps([{"task": i, "instruction": text} for i, text in rows]))
    else:
        for i, text in rows:
            print(f"{i:>2}  {text}")
    return 0


def read_atoms(cfg: AtomsConfig) -> dict[str, object]:
    """Build the task, reset to the settled init state and evaluate every atom."""
    env = make_env(cfg.task, cfg.env)
    try:
        env.reset(cfg.init)
        obj, act = env.labeler.as_dict(env.world_state())
        return {
            "task": env.task_index,
            "init": cfg.init,
            "instruction": env.instruction,
            "object": obj,
            "action": act,
        }
    finally:
        env.close()


def atoms(cfg: AtomsConfig) -> int:
    """Print the atoms at a settled init state (true ones, or all with --all, or JSON with --json)."""
    result = read_atoms(cfg)
    if cfg.json:
        print(json.dumps(result))
        return 0
    print(f"task {result['task']} init {result['init']}: {result['instruction']}")
    for head in HEADS:
        values: dict[str, int] = result[head]  # type: ignore[assignment]
        shown = values if cfg.all else {k: v for k, v in values.items() if v}
        print(f"{head} state ({sum(values.values())} of {len(values)} atoms true):")
        for name, value in shown.items():
            print(f"  {name}" if not cfg.all else f"  {value} {name}")
    return 0
