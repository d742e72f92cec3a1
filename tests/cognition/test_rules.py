"""The shipped rules: each fires on a state built to violate it and on no other; errors in users' rules files."""

from __future__ import annotations

from pathlib import Path

import pytest
from tests.cognition.scenes import (
    APPROACH,
    BOWL,
    BOWL2,
    CARRY,
    COOKIES,
    GOAL,
    PLATE,
    RAMEKIN,
    TOP,
    VOCAB,
    arrays,
)

from vlaprobe.cognition import Cognition, CognitionConfig, RuleEngine
from vlaprobe.errors import VlaprobeError

A, B, C = BOWL2, COOKIES, RAMEKIN
LEFT_CYCLE = {f"left-of({A},{B})", f"left-of({B},{C})", f"left-of({C},{A})"}
RIGHT_CONVERSES = {f"right-of({B},{A})", f"right-of({C},{B})", f"right-of({A},{C})"}

# rule id -> steps (sets of true atoms); the rule must hold at the last step only, and no other rule ever.
CASES: dict[str, list[set[str]]] = {
    "on_and_inside": [APPROACH | {f"on({A},{B})", f"inside({A},{TOP})"}],
    "on_two_supports": [APPROACH | {f"on({A},{B})", f"on({A},{PLATE})"}],
    "on_mutual": [APPROACH | {f"on({A},{B})", f"on({B},{A})"}],
    "on_and_on_table": [APPROACH | {f"on({A},{PLATE})", f"on-table({A})"}],
    "opposite_sides": [
        APPROACH | {f"left-of({A},{B})", f"right-of({B},{A})", f"right-of({A},{B})", f"left-of({B},{A})"}
    ],
    "left_right_converse": [APPROACH | {f"left-of({A},{B})"}],
    "behind_front_converse": [APPROACH | {f"in-front-of({A},{B})"}],
    "order_cycle": [APPROACH | LEFT_CYCLE | RIGHT_CONVERSES],
    "grasped_many": [APPROACH | {f"grasped({A})", f"grasped({B})"}],
    "towards_not_one": [set()],
    "placed_without_grasp": [set(APPROACH), {f"on({BOWL},{PLATE})"}],
    "on_while_grasped": [set(APPROACH), CARRY | {f"on({BOWL},{PLATE})"}],
    "inside_changed_closed": [set(APPROACH), APPROACH | {f"inside({A},{TOP})"}],
}


def run(steps: list[set[str]], **config: object) -> list:
    cog = Cognition(VOCAB.object_atoms, VOCAB.action_atoms, GOAL, CognitionConfig(debounce=1, **config))
    return [cog.step(*arrays(s)) for s in steps]


def test_every_shipped_rule_has_a_case() -> None:
    engine = RuleEngine(VOCAB.object_atoms + VOCAB.action_atoms, GOAL)
    assert set(engine.messages) == set(CASES)


@pytest.mark.parametrize("rule", sorted(CASES))
def test_each_rule_fires_alone_on_a_state_built_to_violate_it(rule: str) -> None:
    steps = run(CASES[rule])
    assert all(not s.violations for s in steps[:-1])
    last = steps[-1]
    assert {v.rule for v in last.violations} == {rule}
    for v in last.violations:
        assert v.since == last.t and "\n" not in v.message and v.message.startswith(v.message.split(":")[0])
        assert v.atoms and all(a in VOCAB.object_atoms + VOCAB.action_atoms for a in v.atoms)


CABINET = TOP.removesuffix("_top_region")
ON_OWN_CABINET = APPROACH | {f"on({A},{CABINET})", f"inside({A},{TOP})"}
"""Inside a drawer and on the drawer's own cabinet (LIBERO-90 task 3): consistent."""


def test_on_the_drawers_own_cabinet_is_not_on_and_inside() -> None:
    engine = RuleEngine(VOCAB.object_atoms + VOCAB.action_atoms, GOAL)
    assert f"part_of({TOP},{CABINET})." in engine.type_facts
    (step,) = run([ON_OWN_CABINET])
    assert "on_and_inside" not in {v.rule for v in step.violations}
    (step,) = run([ON_OWN_CABINET | {f"on({A},{B})"}])  # on another object as well: still flagged
    assert "on_and_inside" in {v.rule for v in step.violations}


def test_reported_atoms_name_the_culprits() -> None:
    (step,) = run(CASES["on_and_inside"])
    assert step.violations[0].atoms == (f"on({A},{B})", f"inside({A},{TOP})")
    (step,) = run(CASES["order_cycle"])
    cycles = {frozenset(v.atoms) for v in step.violations}
    assert cycles == {frozenset(LEFT_CYCLE), frozenset(RIGHT_CONVERSES)}
    (step,) = run([{f"should-move-towards({BOWL})", f"should-move-towards({PLATE})"}])
    goal = f"on({BOWL},{PLATE})"
    assert step.violations[0].atoms == (goal, f"should-move-towards({BOWL})", f"should-move-towards({PLATE})")


def test_consistent_states_and_the_goal_give_no_violation() -> None:
    steps = run(
        [set(APPROACH), {f"grasped({BOWL})", f"should-move-towards({PLATE})"}, {f"on({BOWL},{PLATE})"}]
    )
    assert all(not s.violations for s in steps)


def test_inside_may_change_while_the_drawer_was_open_recently() -> None:
    opened = APPROACH | {f"open({TOP})"}
    steps = [set(APPROACH), set(opened), *[set(APPROACH)] * 3, APPROACH | {f"inside({A},{TOP})"}]
    assert all(not s.violations for s in run(steps, recent_steps=10))
    late = run(steps, recent_steps=2)[-1]
    assert [v.rule for v in late.violations] == ["inside_changed_closed"]


def test_a_user_rule_is_added_to_the_shipped_ones(tmp_path: Path) -> None:
    rules = tmp_path / "mine.lp"
    rules.write_text(
        'message(stove_on, "the stove is on").\n'
        "violation(stove_on, turned_on(K)) :- turned_on(K), object(K).\n"
    )
    (step,) = run([APPROACH | {"turned-on(flat_stove_1)", f"left-of({A},{B})"}], rules=(rules,))
    assert {v.rule for v in step.violations} == {"stove_on", "left_right_converse"}
    stove = next(v for v in step.violations if v.rule == "stove_on")
    assert stove.message == "the stove is on: turned-on(flat_stove_1)"


@pytest.mark.parametrize(
    ("text", "line", "words"),
    [
        ('message(r, "x").\nviolation(r, X) :- on(X,Y) Y.\n', 2, "syntax error"),
        ('message(r, "x").\n\nviolation(r, X) :- lefty(X,Y).\n', 3, "unknown predicate"),
        ("violation(r, X) :- left_of(X).\n", 1, "unknown predicate"),
        ("\n:- on(X,Y), inside(X,C).\n", 2, "without a head"),
        ("violation(r, X) :- not on(X,Y).\n", 1, "unsafe"),
    ],
)
def test_bad_user_rules_are_one_line_errors_naming_file_and_line(
    tmp_path: Path, text: str, line: int, words: str
) -> None:
    path = tmp_path / "bad.lp"
    path.write_text(text)
    with pytest.raises(VlaprobeError) as err:
        RuleEngine(VOCAB.object_atoms + VOCAB.action_atoms, GOAL, rules=(path,))
    message = str(err.value)
    assert f"{path}:{line}:" in message and words in message and "\n" not in message


def test_a_missing_rules_file_is_a_one_line_error(tmp_path: Path) -> None:
    with pytest.raises(VlaprobeError, match="rules file not found"):
        RuleEngine(VOCAB.object_atoms, GOAL, rules=(tmp_path / "none.lp",))
