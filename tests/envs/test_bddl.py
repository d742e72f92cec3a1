"""The BDDL reader: sections, typed names, regions, init facts and the goal conjunction."""

from __future__ import annotations

from pathlib import Path

import pytest

from vlaprobe.envs.bddl import Fact, Named, Region, parse_bddl, read_problem
from vlaprobe.errors import VlaprobeError
from vlaprobe.symbols.goals import Conjunct, GoalConjunction, goal_predicate

TEXT = """
(define (problem LIBERO_Kitchen_Tabletop_Manipulation)
  (:domain robosuite)
  (:language Put the mug in the microwave and close it)
  (:regions
    (mug_init_region (:target kitchen_table) (:ranges ((0.0 -0.1 0.02 -0.08))))
    (heating_region (:target microwave_1))
    (top_side (:target microwave_1))
  )
  (:fixtures kitchen_table - kitchen_table microwave_1 - microwave)
  (:objects porcelain_mug_1 white_yellow_mug_1 - porcelain_mug plate_1 - plate)
  (:obj_of_interest white_yellow_mug_1 microwave_1)
  (:init (On porcelain_mug_1 kitchen_table_mug_init_region) (Open microwave_1))
  (:goal (And (In white_yellow_mug_1 microwave_1_heating_region) (Close microwave_1) (Turnon stove_1)))
)
"""


def test_sections_are_typed() -> None:
    p = parse_bddl(TEXT)
    assert p.problem_class == "libero_kitchen_tabletop_manipulation"
    assert p.fixtures == (Named("kitchen_table", "kitchen_table"), Named("microwave_1", "microwave"))
    assert p.objects == (
        Named("porcelain_mug_1", "porcelain_mug"),
        Named("white_yellow_mug_1", "porcelain_mug"),
        Named("plate_1", "plate"),
    )
    assert p.regions[0] == Region("kitchen_table_mug_init_region", "kitchen_table", "mug_init_region")
    assert [r.name for r in p.regions[1:]] == ["microwave_1_heating_region", "microwave_1_top_side"]
    assert p.obj_of_interest == ("white_yellow_mug_1", "microwave_1")
    assert p.init == (
        Fact("on", ("porcelain_mug_1", "kitchen_table_mug_init_region")),
        Fact("open", ("microwave_1",)),
    )
    assert p.goal == GoalConjunction(
        (
            Conjunct("In", ("white_yellow_mug_1", "microwave_1_heating_region")),
            Conjunct("Close", ("microwave_1",)),
            Conjunct("TurnOn", ("stove_1",)),
        )
    )
    assert (
        str(p.goal)
        == "In(white_yellow_mug_1,microwave_1_heating_region) & Close(microwave_1) & TurnOn(stove_1)"
    )
    assert p.goal.names == {"white_yellow_mug_1", "microwave_1_heating_region", "microwave_1", "stove_1"}


def test_goal_predicates_and_arity() -> None:
    assert [goal_predicate(w) for w in ("on", "IN", "Open", "close", "Turnon", "turnoff")] == [
        "On", "In", "Open", "Close", "TurnOn", "TurnOff",
    ]  # fmt: skip
    with pytest.raises(ValueError, match="'up' is not a goal predicate"):
        goal_predicate("up")
    with pytest.raises(ValueError, match="On takes 2 argument"):
        Conjunct("On", ("a",))


def test_a_goal_without_and_is_one_conjunct() -> None:
    text = TEXT.replace(
        "(And (In white_yellow_mug_1 microwave_1_heating_region) (Close microwave_1) (Turnon stove_1))",
        "(On plate_1 microwave_1_top_side)",
    )
    assert parse_bddl(text).goal == GoalConjunction((Conjunct("On", ("plate_1", "microwave_1_top_side")),))


def test_a_malformed_file_is_one_line(tmp_path: Path) -> None:
    bad = tmp_path / "bad.bddl"
    bad.write_text(TEXT.replace("(:domain robosuite)", "(:domain robosuite"))
    with pytest.raises(VlaprobeError, match=f"cannot read BDDL file {bad}: .*; reinstall LIBERO"):
        read_problem(bad)
    with pytest.raises(VlaprobeError, match="BDDL file not found"):
        read_problem(tmp_path / "none.bddl")
    bad.write_text(TEXT.replace("porcelain_mug_1 white_yellow_mug_1 - porcelain_mug plate_1 - plate", "a b"))
    with pytest.raises(VlaprobeError, match="names without a category"):
        read_problem(bad)
