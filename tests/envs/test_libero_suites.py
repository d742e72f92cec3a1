"""Every suite in the real simulator (one task each): the settled init state's atoms agree with the BDDL ``:init``
and with LIBERO's own predicates, and ``vlaprobe atoms`` prints them (issue #35; the full sweep is future work)."""

from __future__ import annotations

import json
import os
from dataclasses import dataclass, field

import pytest

from vlaprobe.cli import main
from vlaprobe.configs.env import SUITES, EnvConfig, SuiteName
from vlaprobe.envs.bddl import BddlProblem, Fact
from vlaprobe.envs.libero import LiberoTaskEnv
from vlaprobe.symbols import atom
from vlaprobe.symbols.goals import Conjunct, conjunct_value, goal_predicate

pytestmark = pytest.mark.libero

ONE_TASK: dict[SuiteName, int] = {
    "libero_spatial": 4,  # the bowl in the open top drawer
    "libero_object": 0,  # groceries and a basket on the floor
    "libero_goal": 0,  # all drawers closed, the stove off
    "libero_10": 9,  # the microwave open, two mugs on a kitchen table
    "libero_90": 0,  # the top drawer open
}


def our_truth(env: LiberoTaskEnv, fact: Fact, values: dict[str, int]) -> bool:
    """What our atoms (or the scene's close/off rules) say of one BDDL ``:init`` fact: the goal's reading of it
    (:func:`vlaprobe.symbols.goals.conjunct_value`), and ``on-table`` for an ``On`` onto a workspace region (a
    placement region, which the vocabulary has no atom for)."""
    conjunct = Conjunct(goal_predicate(fact.predicate), fact.args)
    value = conjunct_value(conjunct, env.scene, env.world_state(), values)
    return bool(values[atom("on-table", fact.args[0])]) if value is None else value


@dataclass
class InitCheck:
    """What one settled init state says of its BDDL ``:init``: facts checked, our disagreements with LIBERO or
    the BDDL, and facts of the BDDL that LIBERO's own predicate finds false too (the BDDL, not us)."""

    checks: int = 0
    wrong: list[str] = field(default_factory=list)
    unmet: list[str] = field(default_factory=list)


def init_check(env: LiberoTaskEnv, problem: BddlProblem, init: int) -> InitCheck:
    """Reset to ``init`` and check every BDDL ``:init`` fact: our atoms against the fact, and against LIBERO's
    own predicate where its arguments are objects or their regions; no goal conjunct over objects holds yet."""
    env.reset(init)
    obj, _ = env.labeler.as_dict(env.world_state())
    names = set(env.scene.tabletop) | set(env.scene.regions)
    out = InitCheck()
    for fact in problem.init:
        out.checks += 1
        ours = our_truth(env, fact, obj)
        libero = env.libero_predicate(fact.predicate, *fact.args) if set(fact.args) <= names else None
        if libero is not None and ours != libero:
            out.wrong.append(f"init {init}: ours {ours}, LIBERO's {libero} for {fact.predicate}{fact.args}")
        elif not ours and libero is None:
            out.wrong.append(f"init {init}: ours says not {fact.predicate}{fact.args}")
        elif not ours:
            out.unmet.append(f"init {init}: neither LIBERO nor ours finds {fact.predicate}{fact.args}")
    for conjunct in problem.goal.conjuncts:
        if conjunct.predicate in ("On", "In") and set(conjunct.args) <= names:
            out.checks += 1
            if env.libero_predicate(conjunct.predicate, *conjunct.args):
                out.wrong.append(f"init {init}: the goal's {conjunct} holds already")
    return out


SWEEP = os.environ.get("VLAPROBE_LIBERO_SWEEP", "")
"""``VLAPROBE_LIBERO_SWEEP=1``: every task of every suite (minutes); ``=SUITE``: every task of one suite;
``=SUITE/N``: its tasks 0, N, 2N, ... (a sample); else one task per suite."""


def sweep_cases(one_task: dict[SuiteName, int]) -> list[tuple[SuiteName, int]]:
    """The (suite, task) cases of a per-suite LIBERO test: ``one_task`` in CI, the tasks of the sweep
    (``SWEEP``) under it."""
    if SWEEP in ("", "0"):
        return list(one_task.items())
    from vlaprobe.envs.libero import suite_tasks

    suite, _, every = SWEEP.partition("/")
    suites = SUITES if suite == "1" else (suite,)
    step = int(every or 1)
    return [(s, task) for s in suites for task, _ in suite_tasks(s) if task % step == 0]


@pytest.mark.parametrize(("suite", "task"), sweep_cases(ONE_TASK))
def test_init_atoms_agree_with_the_bddl_and_libero(suite: SuiteName, task: int) -> None:
    from tests.envs.test_libero import bddl_scene_agrees_with_the_simulator

    from vlaprobe.envs.bddl_scene import task_bddl

    problem = task_bddl(suite, task)
    with LiberoTaskEnv(task, EnvConfig(suite=suite, render=False)) as env:
        bddl_scene_agrees_with_the_simulator(env)
        checks = [init_check(env, problem, init) for init in (0, 1)]
    wrong = [w for c in checks for w in c.wrong]
    assert not wrong, f"{suite} task {task}: " + "; ".join(wrong)
    if (suite, task) in ONE_TASK.items():
        assert not any(c.unmet for c in checks)


def test_atoms_prints_a_goal_suite_task(capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["atoms", "--suite", "libero_goal", "--task", "0", "--json"]) == 0
    result = json.loads(capsys.readouterr().out)
    assert result["suite"] == "libero_goal" and result["goal"] == "Open(wooden_cabinet_1_middle_region)"
    assert result["object"]["open(wooden_cabinet_1_middle_region)"] == 0
    assert result["object"]["on-table(wine_rack_1)"] == 1
    assert "should-move-towards(akita_black_bowl_1)" in result["undefined"]
    assert not any(a.startswith("should-move-towards") for a in result["action"])
    assert len(result["object"]) == 215 and len(result["action"]) == 4


def sweep() -> None:
    """Every task of every suite, init states 0 and 1: per suite, the checks made, our disagreements, and the BDDL
    facts LIBERO's own predicate finds false too."""
    from vlaprobe.envs.bddl_scene import task_bddl
    from vlaprobe.envs.libero import suite_tasks

    for suite in SUITES:
        total, tasks = InitCheck(), 0
        for task, _ in suite_tasks(suite):
            problem = task_bddl(suite, task)
            with LiberoTaskEnv(task, EnvConfig(suite=suite, render=False)) as env:
                for init in (0, 1):
                    c = init_check(env, problem, init)
                    total.checks += c.checks
                    total.wrong += [f"task {task} {x}" for x in c.wrong]
                    total.unmet += [f"task {task} {x}" for x in c.unmet]
            tasks += 1
        print(
            f"{suite}: {tasks} tasks, {total.checks} checks, {len(total.wrong)} disagreements, "
            f"{len(total.unmet)} BDDL facts false for LIBERO too",
            *total.wrong,
            *total.unmet,
            sep="\n  ",
            flush=True,
        )


if __name__ == "__main__":
    sweep()
