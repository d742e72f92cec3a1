"""Issue 35 (b), (c) in the real simulator, one task per suite: at the settled init and along a goal state reached
by placing the objects, our goal agrees with LIBERO's ``check_success`` and our atoms with LIBERO's own predicates
on every row (``tests/envs/goal_states.py``). ``VLAPROBE_LIBERO_SWEEP=1`` (or ``python -m
tests.envs.test_goal_states [SUITE ...] [--every N | --tasks a,b]``, which prints the counts per suite; ``episodes``
instead of suites: the episode sweep; ``expert SUITE --tasks a,b``: the expert's episode of each task) runs every
task of every suite."""

from __future__ import annotations

import sys

import pytest
from tests.envs.goal_states import RowCheck, task_check
from tests.envs.test_libero_suites import sweep_cases

from vlaprobe.configs.env import SUITES, EnvConfig, SuiteName
from vlaprobe.envs.libero import LiberoTaskEnv

pytestmark = [pytest.mark.libero, pytest.mark.heavy]

ONE_TASK: dict[SuiteName, int] = {
    "libero_spatial": 0,  # On(bowl, plate)
    "libero_object": 0,  # In(alphabet soup, basket)
    "libero_goal": 3,  # In(bowl, the top drawer): the drawer opened first
    "libero_10": 3,  # Close(drawer) & In(bowl, drawer): the bowl rides the drawer in
    "libero_90": 0,  # Open(top drawer)
}


@pytest.mark.parametrize(("suite", "task"), sweep_cases(ONE_TASK))
def test_our_goal_and_atoms_agree_with_libero_at_placed_goal_states(suite: SuiteName, task: int) -> None:
    with LiberoTaskEnv(task, EnvConfig(suite=suite, render=False)) as env:
        check = task_check(env)
    assert not check.goal_wrong, check.goal_wrong[:3]
    assert not check.atom_wrong, dict(check.atom_wrong)
    assert check.atom_checks > 0 and check.goal_rows > 0
    if (suite, task) in ONE_TASK.items():
        assert check.placed == 1 and check.goal_reached > 0 and check.goal_undefined == 0


EPISODES: list[tuple[SuiteName, int, str, int]] = [
    ("libero_spatial", 0, "expert", 300),  # the bowl onto the plate: the episode reaches the goal
    ("libero_goal", 8, "policy", 40),  # random actions of the fake model in another suite's scene
]


@pytest.mark.parametrize(("suite", "task", "driver", "steps"), EPISODES)
def test_our_goal_and_atoms_agree_with_libero_along_episodes(
    suite: SuiteName, task: int, driver: str, steps: int
) -> None:
    """Every row of an episode as collection runs it (the fake model observes: the rows, not the model, are
    checked here; ``python -m tests.envs.test_goal_states episodes`` runs the tiny model)."""
    from tests.collection.fakes import FakePolicy
    from tests.envs.goal_states import episode_check

    from vlaprobe.configs.policy import PolicyConfig

    with LiberoTaskEnv(task, EnvConfig(suite=suite, image_size=64)) as env:
        check = episode_check(env, driver, FakePolicy(PolicyConfig()), max_steps=steps)  # type: ignore[arg-type]
    assert not check.goal_wrong, check.goal_wrong[:3]
    assert not check.atom_wrong, dict(check.atom_wrong)
    assert check.goal_rows > 1 and (driver != "expert" or check.goal_reached > 0)


def sweep(suites: list[str], tasks: list[int] | None = None) -> None:
    """Every task (or ``tasks``) of ``suites``: per suite, the rows and atoms checked and the disagreements."""
    from vlaprobe.envs.libero import suite_tasks

    for suite in suites:
        total = RowCheck()
        not_placed, undefined = [], []
        for task, _ in suite_tasks(suite):  # type: ignore[arg-type]
            if tasks is not None and task not in tasks:
                continue
            with LiberoTaskEnv(task, EnvConfig(suite=suite, render=False)) as env:  # type: ignore[arg-type]
                check = task_check(env)
                if not check.placed:
                    not_placed.append(f"{task} {env.goal_conjunction}")
                if check.goal_undefined:
                    undefined.append(f"{task} {env.goal_conjunction}")
            total.add(check)
        print(
            f"{suite}: {total.tasks} tasks, {total.goal_rows} goal rows ({total.goal_reached} at LIBERO's goal, "
            f"{total.goal_undefined} undefined for us), {len(total.goal_wrong)} goal disagreements; "
            f"{total.atom_checks} atom checks, {sum(total.atom_wrong.values())} disagreements; goal placed in "
            f"{total.placed} of {total.tasks}",
            *total.goal_wrong,
            *(f"{k}: {v} rows" for k, v in total.atom_wrong.items()),
            *(f"not placed: {x}" for x in not_placed),
            *(f"goal undefined: {x}" for x in undefined),
            sep="\n  ",
            flush=True,
        )


def episode_sweep(max_steps: int = 60) -> None:
    """The expert's episodes of every LIBERO-spatial task (init 0; the fake model observes: only the rows are
    checked), and the tiny model's (``max_steps``) in the first three tasks of every other suite: rows checked
    and disagreements per suite and driver."""
    from tests.collection.fakes import FakePolicy
    from tests.envs.goal_states import episode_check

    from vlaprobe.configs.policy import PolicyConfig
    from vlaprobe.envs.libero import suite_tasks
    from vlaprobe.policies import make_policy

    for suite in SUITES:
        tiny = make_policy(PolicyConfig("tiny-libero", device="cpu"), suite)
        runs = [(t, "expert", 300) for t, _ in suite_tasks(suite)] if suite == "libero_spatial" else []
        runs += [(t, "policy", max_steps) for t in (0, 1, 2)]
        for driver in ("expert", "policy"):
            total = RowCheck()
            policy = FakePolicy(PolicyConfig()) if driver == "expert" else tiny
            for task, _, steps in (r for r in runs if r[1] == driver):
                with LiberoTaskEnv(task, EnvConfig(suite=suite, image_size=128)) as env:
                    total.add(episode_check(env, driver, policy, max_steps=steps))  # type: ignore[arg-type]
            if total.tasks:
                print(
                    f"{suite} {driver}: {total.tasks} episodes, {total.goal_rows} rows ({total.goal_reached} at "
                    f"LIBERO's goal, {total.goal_undefined} undefined for us), {len(total.goal_wrong)} goal "
                    f"disagreements; {total.atom_checks} atom checks, {sum(total.atom_wrong.values())} "
                    f"disagreements; {total.placed} episodes ended at the goal",
                    *total.goal_wrong,
                    *(f"{k}: {v} rows" for k, v in total.atom_wrong.items()),
                    sep="\n  ",
                    flush=True,
                )


def expert_sweep(suite: SuiteName, tasks: list[int], max_steps: int = 600) -> None:
    """The expert's episode (init 0) of each of ``tasks``, every row checked: the counts per task."""
    from tests.collection.fakes import FakePolicy
    from tests.envs.goal_states import episode_check

    from vlaprobe.configs.policy import PolicyConfig
    from vlaprobe.errors import VlaprobeError

    for task in tasks:
        with LiberoTaskEnv(task, EnvConfig(suite=suite, image_size=64)) as env:
            try:
                check = episode_check(env, "expert", FakePolicy(PolicyConfig()), max_steps=max_steps)  # type: ignore[arg-type]
            except VlaprobeError as e:  # a goal the expert has no skill for: say so, check the other tasks
                print(f"{suite} task {task} expert ({env.goal_conjunction}): not run: {e}", flush=True)
                continue
            print(
                f"{suite} task {task} expert ({env.goal_conjunction}): {check.goal_rows} rows ({check.goal_reached} "
                f"at LIBERO's goal, {check.goal_undefined} undefined for us), {len(check.goal_wrong)} goal "
                f"disagreements; {check.atom_checks} atom checks, "
                f"{sum(check.atom_wrong.values())} disagreements; ended at the goal: {bool(check.placed)}",
                *check.goal_wrong,
                *(f"{k}: {v} rows" for k, v in check.atom_wrong.items()),
                sep="\n  ",
                flush=True,
            )


if __name__ == "__main__":
    args = sys.argv[1:]
    picked = None
    if "--tasks" in args:  # tasks a,b,c of each suite named
        i = args.index("--tasks")
        picked = [int(t) for t in args[i + 1].split(",")]
        args = args[:i] + args[i + 2 :]
    if args == ["episodes"]:
        episode_sweep()
    elif args[:1] == ["expert"] and picked is not None:  # expert SUITE --tasks a,b: one expert episode each
        expert_sweep(args[1], picked)  # type: ignore[arg-type]
    elif "--every" in args:  # a sample: tasks 0, N, 2N, ... of each suite named
        i = args.index("--every")
        sweep(args[:i] or list(SUITES), list(range(0, 90, int(args[i + 1]))))
    else:
        sweep(args or list(SUITES), picked)
