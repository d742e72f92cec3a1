"""Scenes and goals read from LIBERO's BDDL files, its object source and the asset XMLs (no simulator)."""

from __future__ import annotations

import os
from pathlib import Path

import pytest

from vlaprobe.configs.env import SUITES, EnvConfig
from vlaprobe.envs.bddl_scene import (
    carried_object_goal,
    in_regions,
    pick_place_goal,
    site_joints,
    task_bddl,
    task_goal,
    task_scene,
)
from vlaprobe.envs.libero import suite_tasks
from vlaprobe.envs.libero_source import category_key, object_facts, problem_facts
from vlaprobe.envs.spatial_scene import SPATIAL_GOAL, SPATIAL_SCENE
from vlaprobe.errors import VlaprobeError
from vlaprobe.experts.planner import check_tasks_plannable, perturbation_goal
from vlaprobe.symbols import Articulation, Goal, build_vocabulary
from vlaprobe.symbols.goals import Conjunct

REAL_ASSETS = os.environ.get("VLAPROBE_LIBERO_ASSETS")
pytestmark = pytest.mark.skipif(not REAL_ASSETS, reason="needs LIBERO's assets (VLAPROBE_LIBERO_ASSETS)")


def test_every_spatial_task_reads_as_the_spatial_scene() -> None:
    for task, _ in suite_tasks("libero_spatial"):
        scene = task_scene("libero_spatial", task)
        assert scene == SPATIAL_SCENE, task
        assert pick_place_goal(task_goal("libero_spatial", task), scene) == SPATIAL_GOAL
    vocab = build_vocabulary(SPATIAL_SCENE)
    assert (len(vocab.object_atoms), len(vocab.action_atoms)) == (224, 12)


def test_libero_source_facts() -> None:
    facts = object_facts()
    cabinet, stove, microwave = facts["wooden_cabinet"], facts["flat_stove"], facts["microwave"]
    assert cabinet.xml == "articulated_objects/wooden_cabinet.xml"
    assert cabinet.is_open == Articulation(-0.14, below=True, strict=True)
    assert cabinet.is_close == Articulation(0.0, below=False, strict=True)
    assert stove.turn_on == Articulation(0.5, below=False, strict=False) and stove.is_open is None
    assert microwave.is_open == Articulation(-1.3, below=True) and microwave.is_close == Articulation(
        -0.005, False, True
    )
    assert facts["akita_black_bowl"].xml == "stable_scanned_objects/akita_black_bowl/akita_black_bowl.xml"
    assert facts["alphabet_soup"].xml.startswith("stable_hope_objects/")
    assert category_key("Chefmate8Frypan") == "chefmate_8_frypan"
    problems = problem_facts()
    assert problems["libero_tabletop_manipulation"].workspace == "table"
    assert problems["libero_floor_manipulation"].workspace == "floor"
    assert (
        problems["libero_kitchen_tabletop_manipulation"].scene_xml
        == "scenes/libero_kitchen_tabletop_base_style.xml"
    )


def test_articulation_rules_compare_as_libero_does() -> None:
    import numpy as np

    q = np.array([-0.2, -0.14, 0.0, 0.5])
    assert Articulation(-0.14, below=True).is_active(q).tolist() == [True, False, False, False]
    assert Articulation(0.5, below=False).is_active(q).tolist() == [False, False, False, True]
    assert Articulation(0.0, below=False, strict=True).is_active(q).tolist() == [False, False, False, True]
    assert Articulation(0.0, below=True, strict=False).is_active(q).tolist() == [True, True, True, False]


def test_drawers_sit_on_joints_tops_do_not() -> None:
    joints = site_joints(Path(str(REAL_ASSETS)) / "articulated_objects/wooden_cabinet.xml")
    assert joints["top_region"] == ("top_level",) and joints["bottom_region"] == ("bottom_level",)
    assert joints["top_side"] == ()
    assert ("basket", "contain_region") in in_regions() and ("wooden_cabinet", "top_side") not in in_regions()


def test_goal_suite_scene_and_goals() -> None:
    scene = task_scene("libero_goal", 0)
    assert scene.pickupable == ("akita_black_bowl_1", "cream_cheese_1", "wine_bottle_1", "plate_1")
    assert scene.fixtures == ("wooden_cabinet_1", "flat_stove_1", "wine_rack_1")
    assert (
        scene.surfaces[-1] == "wine_rack_1_top_region"
        and scene.region_parent["wine_rack_1_top_region"] == "wine_rack_1"
    )
    goals = [task_goal("libero_goal", t) for t, _ in suite_tasks("libero_goal")]
    assert goals[0].conjuncts == (Conjunct("Open", ("wooden_cabinet_1_middle_region",)),)
    assert {c.predicate for g in goals for c in g.conjuncts} == {"On", "In", "Open", "TurnOn"}
    assert pick_place_goal(goals[0], scene) is None  # Open(...): no pick-and-place
    assert [str(pick_place_goal(g, scene)) for g in goals].count("None") == 10 - sum(
        1
        for g in goals
        if len(g.conjuncts) == 1
        and g.conjuncts[0].predicate == "On"
        and g.conjuncts[0].args[1] in scene.tabletop
    )
    on_region = next(g for g in goals if str(g) == "On(akita_black_bowl_1,flat_stove_1_cook_region)")
    assert pick_place_goal(on_region, scene) is None  # onto a region, not an object: not yet


def test_basket_microwave_and_caddy_are_receptacles() -> None:
    basket = task_scene("libero_object", 0)
    assert basket.fixtures == () and "basket_1" in basket.pickupable
    assert (
        basket.receptacles == ("basket_1_contain_region",)
        and basket.region_parent["basket_1_contain_region"] == "basket_1"
    )
    assert "inside(alphabet_soup_1,basket_1_contain_region)" in build_vocabulary(basket).object_atoms
    microwave = task_scene("libero_10", 9)
    assert microwave.doors == ("microwave_1",) and microwave.receptacles == ("microwave_1_heating_region",)
    assert microwave.surfaces == ("microwave_1_top_side",) and microwave.containers == ()
    assert microwave.door_articulation == (Articulation(-1.3, below=True),)
    assert microwave.close_articulation == (Articulation(-0.005, below=False, strict=True),)
    assert "open(microwave_1)" in build_vocabulary(microwave).object_atoms
    assert [str(c) for c in task_goal("libero_10", 9).conjuncts] == [
        "In(white_yellow_mug_1,microwave_1_heating_region)",
        "Close(microwave_1)",
    ]
    caddy = task_scene("libero_10", 5)
    assert len([r for r in caddy.receptacles if r.startswith("desk_caddy_1_")]) == 4


@pytest.mark.parametrize("suite", SUITES)
def test_every_task_of_every_suite_reads(suite: str) -> None:
    """Every category resolves to an asset XML; workspace fixtures are not objects; every goal argument is an
    object, a region of the scene or a region on the workspace."""
    for task, _ in suite_tasks(suite):  # type: ignore[arg-type]
        problem = task_bddl(suite, task)  # type: ignore[arg-type]
        scene = task_scene(suite, task)  # type: ignore[arg-type]
        workspace = problem_facts()[problem.problem_class].workspace
        assert not {f.name for f in problem.fixtures if f.category == workspace} & set(scene.tabletop)
        regions = {r.name for r in problem.regions}
        for name in problem.goal.names:
            assert name in scene.tabletop or name in scene.regions or name in regions, (suite, task, name)
        assert len(scene.close_articulation) == len(scene.openable)


def test_perturb_check_accepts_every_basket_task_and_the_drawer_and_refuses_a_push() -> None:
    """``--perturb`` on LIBERO-object (``In(item, basket_1_contain_region)``), the goal suite's fixture regions
    and its drawer task (``In(bowl, wooden_cabinet_1_top_region)``) passes the up-front check; the plate pushed
    onto the table's region is refused, naming it."""
    tasks = tuple(t for t, _ in suite_tasks("libero_object"))
    check_tasks_plannable(EnvConfig(suite="libero_object"), tasks, expert=True, perturb=True)
    check_tasks_plannable(EnvConfig(suite="libero_goal"), (1, 2, 3, 4, 6, 8, 9), expert=True, perturb=True)
    with pytest.raises(VlaprobeError, match=r"libero_goal task 5's goal is On\(plate_1,main_table_stove"):
        check_tasks_plannable(EnvConfig(suite="libero_goal"), (5,), expert=True, perturb=True)


def test_perturb_acts_on_the_last_placed_object_of_libero_10_and_as_before_elsewhere() -> None:
    """LIBERO-10: the object the plan places last where it ends with a pick-and-place, nothing where it ends
    with closing the drawer, a place onto the table's region or has no skill; every goal of one conjunct of
    the other suites: exactly ``carried_object_goal`` (what ``--perturb`` acted on before)."""
    last = {
        0: Goal("tomato_sauce_1", "basket_1"),
        1: Goal("butter_1", "basket_1"),
        2: Goal("moka_pot_1", "flat_stove_1_cook_region"),
        4: Goal("white_yellow_mug_1", "plate_2"),
        5: Goal("black_book_1", "desk_caddy_1_back_contain_region"),
        7: Goal("cream_cheese_1", "basket_1"),
        8: Goal("moka_pot_2", "flat_stove_1_cook_region"),
    }
    for task in range(10):
        assert perturbation_goal(task_goal("libero_10", task), task_scene("libero_10", task))[0] == last.get(
            task
        )
    for suite in ("libero_spatial", "libero_object", "libero_goal", "libero_90"):
        for task, _ in suite_tasks(suite):  # type: ignore[arg-type]
            goal, scene = task_goal(suite, task), task_scene(suite, task)  # type: ignore[arg-type]
            if len(goal.conjuncts) == 1:
                assert perturbation_goal(goal, scene) == (carried_object_goal(goal, scene), ""), (suite, task)
