"""The planner on hand-made goals and scenes: which skills, in which order, and what it refuses."""

from __future__ import annotations

import pytest

from vlaprobe.errors import VlaprobeError
from vlaprobe.experts import Step, plan_steps
from vlaprobe.symbols import Articulation, Scene
from vlaprobe.symbols.goals import Conjunct, GoalConjunction

DRAWER = "wooden_cabinet_1_top_region"
SCENE = Scene(
    pickupable=("akita_black_bowl_1", "cream_cheese_1", "plate_1", "porcelain_mug_1"),
    fixtures=("wooden_cabinet_1", "flat_stove_1", "basket_1"),
    containers=(DRAWER,),
    container_articulation=(Articulation(-0.14, below=True),),
    surfaces=("flat_stove_1_cook_region",),
    on_off=("flat_stove_1",),
    on_off_articulation=(Articulation(0.5, below=False),),
    receptacles=("basket_1_contain_region",),
    doors=("microwave_1",),
    door_articulation=(Articulation(-0.5, below=True),),
)


def goal(*conjuncts: tuple[str, ...]) -> GoalConjunction:
    return GoalConjunction(tuple(Conjunct(c[0], c[1:]) for c in conjuncts))  # type: ignore[arg-type]


def test_one_conjunct_one_skill() -> None:
    assert plan_steps(goal(("On", "akita_black_bowl_1", "flat_stove_1_cook_region")), SCENE) == [
        Step("rim_place", "akita_black_bowl_1", "flat_stove_1_cook_region")
    ]
    assert plan_steps(goal(("In", "cream_cheese_1", "basket_1_contain_region")), SCENE) == [
        Step("body_place", "cream_cheese_1", "basket_1_contain_region")
    ]
    assert plan_steps(goal(("TurnOn", "flat_stove_1")), SCENE) == [Step("turn_on", "flat_stove_1")]
    assert plan_steps(goal(("Open", DRAWER)), SCENE) == [Step("open", DRAWER)]


def test_a_plate_onto_a_table_region_is_pushed_but_onto_an_object_is_carried() -> None:
    assert plan_steps(goal(("On", "plate_1", "main_table_stove_front_region")), SCENE) == [
        Step("push", "plate_1", "main_table_stove_front_region")
    ]
    assert plan_steps(goal(("On", "plate_1", "flat_stove_1_cook_region")), SCENE)[0].skill == "body_place"


def test_order_opens_first_places_then_closes_last() -> None:
    steps = plan_steps(
        goal(("Close", DRAWER), ("In", "porcelain_mug_1", DRAWER), ("TurnOn", "flat_stove_1")), SCENE
    )
    assert steps == [
        Step("clear", "porcelain_mug_1", DRAWER),  # out of the way of the drawer, if it stands there
        Step("open", DRAWER),  # putting something In a drawer opens it first
        Step("turn_on", "flat_stove_1"),
        Step("rim_place", "porcelain_mug_1", DRAWER),
        Step("close", DRAWER),
    ]


def test_two_objects_into_one_basket_and_a_repeated_open_are_planned_once_each() -> None:
    steps = plan_steps(
        goal(("In", "cream_cheese_1", DRAWER), ("Open", DRAWER), ("In", "akita_black_bowl_1", DRAWER)), SCENE
    )
    assert [s.skill for s in steps] == ["clear", "clear", "open", "rim_place", "body_place"]


@pytest.mark.parametrize(
    "conjunct",
    [
        ("TurnOn", "wooden_cabinet_1"),
        ("Open", "flat_stove_1"),
        ("On", "wooden_cabinet_1", "plate_1"),
        ("Close", "microwave_1"),  # a door: no skill yet
    ],
)
def test_a_conjunct_without_a_skill_is_refused_naming_it(conjunct: tuple[str, ...]) -> None:
    with pytest.raises(VlaprobeError, match=rf"no skill for the goal conjunct {conjunct[0]}\("):
        plan_steps(goal(conjunct), SCENE)
