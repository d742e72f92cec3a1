"""What ``--perturb`` acts on (``carried_object_goal``), on hand-made scenes and goals: one ``On`` between
objects, one ``In`` into a movable object's region (a basket), one ``On``/``In`` onto or into a region of a fixture
(a cabinet's top, a microwave) or into a drawer; the table's placement regions, opening and several conjuncts
stay refused (``experts.planner.perturbation_goal`` picks the conjunct of several). The labeler's ``pick_place_goal`` is unchanged (no ``In``)."""

from __future__ import annotations

from vlaprobe.envs.bddl_scene import carried_object_goal, pick_place_goal
from vlaprobe.symbols import Articulation, Goal, Scene
from vlaprobe.symbols.goals import Conjunct, GoalConjunction

BASKET = Scene(
    pickupable=("ketchup_1", "basket_1", "milk_1"),
    fixtures=(),
    containers=(),
    container_articulation=(),
    region_parent={"basket_1_contain_region": "basket_1"},
    receptacles=("basket_1_contain_region",),
)
KITCHEN = Scene(
    pickupable=("akita_black_bowl_1", "plate_1"),
    fixtures=("wooden_cabinet_1", "microwave_1"),
    containers=("wooden_cabinet_1_top_region",),
    container_articulation=(Articulation(-0.14, below=True),),
    region_parent={
        "wooden_cabinet_1_top_region": "wooden_cabinet_1",
        "microwave_1_heating_region": "microwave_1",
        "wooden_cabinet_1_top_side": "wooden_cabinet_1",
    },
    receptacles=("microwave_1_heating_region",),
    surfaces=("wooden_cabinet_1_top_side",),
)


def goal(*conjuncts: tuple[str, tuple[str, ...]]) -> GoalConjunction:
    return GoalConjunction(tuple(Conjunct(p, a) for p, a in conjuncts))  # type: ignore[arg-type]


def test_in_a_basket_is_carried_into_the_basket_object() -> None:
    into = goal(("In", ("ketchup_1", "basket_1_contain_region")))
    assert carried_object_goal(into, BASKET) == Goal(pick="ketchup_1", place="basket_1")
    assert pick_place_goal(into, BASKET) is None  # the labeler's goal stays as it was


def test_on_between_objects_is_the_pick_place_goal() -> None:
    on = goal(("On", ("akita_black_bowl_1", "plate_1")))
    assert (
        carried_object_goal(on, KITCHEN)
        == pick_place_goal(on, KITCHEN)
        == Goal("akita_black_bowl_1", "plate_1")
    )


def test_a_fixture_region_without_a_joint_is_the_place_itself() -> None:
    for conjunct in [
        ("On", ("akita_black_bowl_1", "wooden_cabinet_1_top_side")),  # a fixture's surface
        ("In", ("akita_black_bowl_1", "microwave_1_heating_region")),  # a fixture's receptacle
    ]:
        assert carried_object_goal(goal(conjunct), KITCHEN) == Goal("akita_black_bowl_1", conjunct[1][1])


def test_into_a_drawer_is_the_drawer_region_but_onto_it_is_refused() -> None:
    drawer = "wooden_cabinet_1_top_region"
    into, onto = goal(("In", ("akita_black_bowl_1", drawer))), goal(("On", ("akita_black_bowl_1", drawer)))
    assert carried_object_goal(into, KITCHEN) == Goal("akita_black_bowl_1", drawer)
    assert carried_object_goal(onto, KITCHEN) is None


def test_table_regions_openings_and_conjunctions_are_refused() -> None:
    refused = [
        goal(("On", ("plate_1", "main_table_stove_front_region"))),  # a placement region of the table: a push
        goal(("Open", ("wooden_cabinet_1_top_region",))),
        goal(("In", ("basket_1", "basket_1_contain_region"))),  # the basket into itself
        goal(("On", ("ketchup_1", "basket_1_contain_region"))),  # On a movable receptacle's region
    ]
    for g in refused:
        assert carried_object_goal(g, KITCHEN if "basket" not in str(g) else BASKET) is None, g
    two = goal(
        ("In", ("ketchup_1", "basket_1_contain_region")), ("In", ("milk_1", "basket_1_contain_region"))
    )
    assert carried_object_goal(two, BASKET) is None
