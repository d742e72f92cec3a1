"""Subgoals of any goal conjunction (``vlaprobe.cognition.plan``) on hand-made beliefs over LIBERO-spatial's
vocabulary: each conjunct kind, and a conjunction in the expert planner's order."""

from __future__ import annotations

import pytest
from tests.cognition.scenes import BOWL, SCENE, TOP, VOCAB, arrays

from vlaprobe.cognition import Cognition, CognitionConfig
from vlaprobe.cognition.plan import TaskGoal, expert_order, task_goal
from vlaprobe.errors import VlaprobeError
from vlaprobe.symbols.goals import Conjunct, GoalConjunction

CABINET = SCENE.region_parent[TOP]
STOVE = SCENE.on_off[0]


def goal(*conjuncts: Conjunct) -> TaskGoal:
    return task_goal(GoalConjunction(conjuncts), SCENE)


def run(g: TaskGoal, steps: list[set[str]]) -> list:
    cog = Cognition(VOCAB.object_atoms, VOCAB.action_atoms, g, CognitionConfig(debounce=1))
    return [cog.step(*arrays(s)) for s in steps]


def done(steps: list) -> list[str]:
    return [e.message.split(": ", 1)[1] for s in steps for e in s.events if e.kind == "subgoal_done"]


def test_in_a_drawer_goes_towards_the_object_then_its_cabinet() -> None:
    g = goal(Conjunct("In", (BOWL, TOP)))
    towards_bowl, towards_cab = f"should-move-towards({BOWL})", f"should-move-towards({CABINET})"
    inside = f"inside({BOWL},{TOP})"
    steps = run(
        g,
        [{towards_bowl}] * 2
        + [{f"grasped({BOWL})", towards_cab}] * 2
        + [{f"grasped({BOWL})"}]
        + [{inside, f"open({TOP})"}] * 2,
    )
    assert done(steps) == [towards_bowl, f"grasped({BOWL})", towards_cab, inside]
    assert steps[5].goal_reached and steps[-1].progress == 1.0 and not steps[4].goal_reached


@pytest.mark.parametrize(
    ("predicate", "thing", "last", "start", "end"),
    [
        ("Open", TOP, f"open({TOP})", set(), {f"open({TOP})"}),
        ("Close", TOP, f"not(open({TOP}))", {f"open({TOP})"}, set()),
        ("TurnOn", STOVE, f"turned-on({STOVE})", set(), {f"turned-on({STOVE})"}),
        ("TurnOff", STOVE, f"not(turned-on({STOVE}))", {f"turned-on({STOVE})"}, set()),
    ],
)
def test_a_switch_goes_towards_its_handle_then_the_articulation(
    predicate: str, thing: str, last: str, start: set[str], end: set[str]
) -> None:
    holder = CABINET if thing == TOP else STOVE
    towards = f"should-move-towards({holder})"
    steps = run(goal(Conjunct(predicate, (thing,))), [start | {towards}] * 2 + [start] + [end] * 2)  # type: ignore[arg-type]
    assert [g.name for g in steps[0].subgoals] == [towards, last]
    assert done(steps) == [towards, last] and steps[-1].goal_reached and not steps[2].goal_reached
    assert [e.t for s in steps for e in s.events if e.kind == "subgoal_done"] == [2, 3]


def test_an_articulation_undone_is_a_regression() -> None:
    steps = run(goal(Conjunct("Open", (TOP,))), [{f"open({TOP})"}] * 2 + [set()] * 3)
    cog_steps = [s for s in steps if any(e.kind == "regression" for e in s.events)]
    assert steps[0].goal_reached and not cog_steps  # 3 steps < the default regression wait
    steps = run(goal(Conjunct("Open", (TOP,))), [{f"open({TOP})"}] * 2 + [set()] * 9)
    assert any(e.kind == "regression" for s in steps for e in s.events) and not steps[-1].goal_reached


def test_a_conjunction_is_tracked_in_the_planners_order() -> None:
    # BDDL order: place, close, open, turn on; the planner: open, turn on, place, close
    bddl = (
        Conjunct("In", (BOWL, TOP)),
        Conjunct("Close", (SCENE.containers[1],)),
        Conjunct("Open", (TOP,)),
        Conjunct("TurnOn", (STOVE,)),
    )
    order = expert_order(GoalConjunction(bddl), SCENE)
    assert order == (bddl[2], bddl[3], bddl[0], bddl[1])
    g = goal(*bddl)
    names = [s.name for s in run(g, [set()])[0].subgoals]
    assert names[:2] == [f"should-move-towards({CABINET})", f"open({TOP})"] and len(names) == 2 + 2 + 4 + 2
    # the later conjuncts' relations count only once the earlier ones are done
    lit = {f"turned-on({STOVE})", f"inside({BOWL},{TOP})"}
    steps = run(g, [lit] * 2 + [lit | {f"open({TOP})"}] * 2)
    assert not steps[1].goal_reached and steps[1].progress == 0.0
    assert steps[-1].progress == (2 + 2) / 10  # Open, TurnOn done; the place needs its grasp first


def test_the_pick_and_place_goal_is_the_rules_goal_fact_and_other_goals_have_none() -> None:
    spatial = goal(Conjunct("On", (BOWL, "plate_1")))
    assert spatial.pick_place is not None and spatial == TaskGoal(
        spatial.conjuncts, spatial.parents, spatial.pick_place
    )
    cog = Cognition(VOCAB.object_atoms, VOCAB.action_atoms, goal(Conjunct("Open", (TOP,))))
    assert not [f for f in cog.rules.type_facts if f.startswith("goal(")]
    # no directive for such goals (the labeler leaves it undefined): no towards_not_one on an empty state
    assert not run(goal(Conjunct("Open", (TOP,))), [set()] * 3)[-1].violations


def test_a_goal_our_atoms_cannot_read_is_one_line() -> None:
    g = TaskGoal((Conjunct("On", ("plate_1", "main_table_stove_front_region")),))
    with pytest.raises(
        VlaprobeError, match=r"goal On\(plate_1,main_table_stove_front_region\) needs the atom"
    ):
        Cognition(VOCAB.object_atoms, VOCAB.action_atoms, g)
