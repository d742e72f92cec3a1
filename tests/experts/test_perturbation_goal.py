"""What ``--perturb`` acts on for a goal of several conjuncts (``perturbation_goal``), on hand-made scenes: the
object the plan places last; nothing (with the reason) where the plan ends with closing, pushing or a place
``--perturb`` does not take. One conjunct: exactly ``carried_object_goal`` (the draws of the goals that worked
before stay the same)."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest
from tests.collection.fakes import FakeEnv

from vlaprobe.envs.bddl_scene import carried_object_goal
from vlaprobe.experts.planner import perturbation_goal
from vlaprobe.rollout.perturb import PerturbSpec, episode_perturber, perturb_target
from vlaprobe.symbols import Articulation, Goal, Scene
from vlaprobe.symbols.goals import Conjunct, GoalConjunction

DRAWER = "wooden_cabinet_1_top_region"
SCENE = Scene(
    pickupable=("akita_black_bowl_1", "cream_cheese_1", "butter_1", "plate_1", "porcelain_mug_1", "basket_1"),
    fixtures=("wooden_cabinet_1", "flat_stove_1"),
    containers=(DRAWER,),
    container_articulation=(Articulation(-0.14, below=True),),
    surfaces=("flat_stove_1_cook_region",),
    on_off=("flat_stove_1",),
    on_off_articulation=(Articulation(0.5, below=False),),
    region_parent={
        DRAWER: "wooden_cabinet_1",
        "flat_stove_1_cook_region": "flat_stove_1",
        "basket_1_contain_region": "basket_1",
    },
    receptacles=("basket_1_contain_region",),
)
BASKET = "basket_1_contain_region"


def goal(*conjuncts: tuple[str, ...]) -> GoalConjunction:
    return GoalConjunction(tuple(Conjunct(c[0], c[1:]) for c in conjuncts))  # type: ignore[arg-type]


@pytest.mark.parametrize(
    ("conjuncts", "chosen"),
    [  # LIBERO-10 task 0/1/7: two objects into the basket: the second one (the plan keeps the goal's order)
        ((("In", "cream_cheese_1", BASKET), ("In", "butter_1", BASKET)), Goal("butter_1", "basket_1")),
        ((("In", "butter_1", BASKET), ("In", "cream_cheese_1", BASKET)), Goal("cream_cheese_1", "basket_1")),
        # a body pick runs after a rim pick whatever the goal's order
        (
            (("In", "cream_cheese_1", BASKET), ("On", "porcelain_mug_1", "plate_1")),
            Goal("cream_cheese_1", "basket_1"),
        ),
        # LIBERO-90 task 8: the drawer opened, then the bowl put in
        ((("Open", DRAWER), ("In", "akita_black_bowl_1", DRAWER)), Goal("akita_black_bowl_1", DRAWER)),
        # LIBERO-10 task 2/8: the stove is turned on first, the pot placed last
        (
            (("TurnOn", "flat_stove_1"), ("On", "cream_cheese_1", "flat_stove_1_cook_region")),
            Goal("cream_cheese_1", "flat_stove_1_cook_region"),
        ),
    ],
)
def test_the_object_placed_last_is_perturbed(conjuncts: tuple[tuple[str, ...], ...], chosen: Goal) -> None:
    assert perturbation_goal(goal(*conjuncts), SCENE) == (chosen, "")


@pytest.mark.parametrize(
    ("conjuncts", "why"),
    [
        (
            (("Close", DRAWER), ("In", "akita_black_bowl_1", DRAWER)),
            f"ends with close {DRAWER}, not with a pick",
        ),
        (
            (("In", "butter_1", BASKET), ("On", "plate_1", "main_table_stove_front_region")),
            "ends with push plate_1, not with a pick",
        ),
        (  # LIBERO-10 task 6: the pudding onto a placement region of the table (no site: nowhere to knock from)
            (("On", "porcelain_mug_1", "plate_1"), ("On", "butter_1", "main_table_plate_right_region")),
            "ends with On(butter_1,main_table_plate_right_region), a place",
        ),
        ((("In", "butter_1", BASKET), ("Close", "microwave_1")), "the scripted expert has no plan for it"),
    ],
)
def test_a_plan_ending_otherwise_is_refused_with_its_reason(
    conjuncts: tuple[tuple[str, ...], ...], why: str
) -> None:
    chosen, reason = perturbation_goal(goal(*conjuncts), SCENE)
    assert chosen is None and why in reason


@pytest.mark.parametrize(
    "conjunct",
    [
        ("On", "akita_black_bowl_1", "plate_1"),
        ("In", "butter_1", BASKET),
        ("On", "porcelain_mug_1", "flat_stove_1_cook_region"),
        ("In", "akita_black_bowl_1", DRAWER),
        ("TurnOn", "flat_stove_1"),
        ("On", "plate_1", "main_table_stove_front_region"),
    ],
)
def test_one_conjunct_is_exactly_carried_object_goal(conjunct: tuple[str, ...]) -> None:
    assert perturbation_goal(goal(conjunct), SCENE) == (carried_object_goal(goal(conjunct), SCENE), "")


def test_the_worker_keeps_the_envs_own_goal_and_asks_the_planner_for_several_conjuncts() -> None:
    two = goal(("In", "cream_cheese_1", BASKET), ("In", "butter_1", BASKET))
    env = SimpleNamespace(scene=SCENE, goal_conjunction=two, perturb_goal=None)
    assert perturb_target(env) == Goal("butter_1", "basket_1")  # type: ignore[arg-type]
    env.perturb_goal = Goal("akita_black_bowl_1", "plate_1")  # one conjunct: the env's answer, untouched
    assert perturb_target(env) == Goal("akita_black_bowl_1", "plate_1")  # type: ignore[arg-type]
    env.goal_conjunction, env.perturb_goal = goal(("TurnOn", "flat_stove_1")), None
    assert perturb_target(env) is None  # type: ignore[arg-type]


def test_the_worker_gives_the_drawers_keep_out_only_to_a_goal_into_a_drawer() -> None:
    """Other goals keep their perturber as it was (no keep-out: their spots stay bitwise the same)."""
    env = FakeEnv(0, None)
    assert episode_perturber(PerturbSpec(drop=1.0), 0, env, 600).keep_out is None  # type: ignore[union-attr]
    env.perturb_goal = Goal("bowl", "cabinet_top")  # the fake scene's drawer
    keep_out = episode_perturber(PerturbSpec(drop=1.0), 0, env, 600).keep_out  # type: ignore[union-attr]
    assert keep_out is not None and np.array_equal(keep_out()[0][1], env.drawer_fronts()[0][1])
