"""Checks of the configs that need the suite's task list or BDDL files (no simulator, no assets).

The range checks that need nothing are in ``vlaprobe.configs.checks``; configs never import envs.
"""

from __future__ import annotations

import re

from vlaprobe.configs.checks import at_least, check_env
from vlaprobe.configs.env import EnvConfig, SuiteName
from vlaprobe.configs.suite import AtomsConfig, TasksConfig
from vlaprobe.errors import VlaprobeError


def check_tasks(tasks: tuple[int, ...], suite: SuiteName, flag: str) -> list[int]:
    """Every selected task exists in ``suite`` (read from LIBERO's task list: no assets, no model); the suite's
    task indices."""
    from vlaprobe.envs.libero import suite_tasks

    known = [i for i, _ in suite_tasks(suite)]
    unknown = [t for t in tasks if t not in known]
    if unknown:
        raise VlaprobeError(
            f"{flag} {unknown} do not exist; {suite} has tasks 0-{max(known)} (see `vlaprobe tasks`)"
        )
    return known


def check_inits(env: EnvConfig, tasks: tuple[int, ...]) -> None:
    """With ``--inits sampled`` (or ``sampled-swap``), every selected task's BDDL lets LIBERO's placement sampler
    place its objects, and with ``sampled-swap`` its instruction has a form whose referent can be checked after a
    swap (read from the BDDL files: no simulator)."""
    if env.inits == "fixed":
        return
    from vlaprobe.envs.libero import suite_tasks, task_problem
    from vlaprobe.envs.placements import sampling_problems
    from vlaprobe.envs.referents import instruction_form

    instructions = dict(suite_tasks(env.suite))
    for task in tasks or tuple(instructions):
        problem = task_problem(task, env.suite)
        problems = sampling_problems(problem)
        if problems:
            raise VlaprobeError(
                f"--inits {env.inits}: task {task}'s regions cannot be sampled ({'; '.join(problems)}); "
                "use --inits fixed or leave the task out (--tasks)"
            )
        goal = problem.get("goal_state", [])
        pick = goal[0][1] if len(goal) == 1 and len(goal[0]) == 3 else ""
        if env.inits == "sampled-swap" and instruction_form(instructions[task], pick) is None:
            raise VlaprobeError(
                f"--inits sampled-swap: task {task}'s instruction {instructions[task]!r} does not describe the "
                "object to pick in a form that can be checked after a swap; use --inits sampled or leave it out"
            )


def check_atoms(cfg: AtomsConfig) -> None:
    """The options of ``vlaprobe atoms``, before the simulator is built (a task is an index in plain digits or
    an exact instruction: other digit characters such as "²" are neither)."""
    from vlaprobe.envs.libero import num_init_states, suite_tasks

    tasks = suite_tasks(cfg.env.suite)
    task = cfg.task.strip() if isinstance(cfg.task, str) else cfg.task
    if isinstance(task, str) and re.fullmatch(r"-?[0-9]{1,6}", task):
        task = int(task)
    if isinstance(task, int) and not 0 <= task < len(tasks):
        raise VlaprobeError(f"--task {task} out of range; {cfg.env.suite} has tasks 0-{len(tasks) - 1}")
    if isinstance(task, str) and task.lower() not in {text.lower() for _, text in tasks}:
        raise VlaprobeError(
            f"--task {task[:80]!r} is neither a task index nor an instruction of {cfg.env.suite}; see `vlaprobe tasks`"
        )
    at_least(cfg.init, 0, "--init")
    check_env(cfg.env)
    inits = num_init_states(cfg.env.suite, task if isinstance(task, int) else 0)
    if cfg.init >= inits:
        raise VlaprobeError(f"--init {cfg.init} does not exist; the task has init states 0-{inits - 1}")


def precheck(cfg: object) -> None:
    """Checks the CLI runs before a command whose own function has none up front (``atoms``, ``tasks``). Every
    suite is taken by every command: ``collect`` and ``run`` refuse the tasks whose goal no expert skill handles
    (``experts.planner.check_tasks_plannable``), ``serve`` an expert episode of one."""
    if isinstance(cfg, AtomsConfig):
        check_atoms(cfg)
    elif isinstance(cfg, TasksConfig):
        check_env(cfg.env)
