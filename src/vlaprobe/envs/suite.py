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
    """Build the task, reset to the settled init state and evaluate every defined atom (atoms without a
    definition for the task's goal are listed under "undefined", not given a value)."""
    env = make_env(cfg.task, cfg.env)
    try:
        env.reset(cfg.init)
        obj, act = env.labeler.as_dict(env.world_state())
        undefined = env.labeler.undefined_action_atoms
        return {
            "suite": cfg.env.suite,
            "task": env.task_index,
            "init": cfg.init,
            "instruction": env.instruction,
            "goal": str(getattr(env, "goal_conjunction", "")),
            "object": obj,
            "action": {k: v for k, v in act.items() if k not in undefined},
            "undefined": list(undefined),
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
    print(f"goal: {result['goal']}")
    for head in HEADS:
        values: dict[str, int] = result[head]  # type: ignore[assignment]
        shown = values if cfg.all else {k: v for k, v in values.items() if v}
        print(f"{head} state ({sum(values.values())} of {len(values)} atoms true):")
        for name, value in shown.items():
            print(f"  {name}" if not cfg.all else f"  {value} {name}")
    undefined: list[str] = result["undefined"]  # type: ignore[assignment]
    if undefined:
        print(
            f"undefined for this goal ({len(undefined)} atoms: should-move-towards follows pick-and-place goals only)"
        )
    return 0
