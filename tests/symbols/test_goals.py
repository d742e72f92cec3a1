"""Our goal on hand-made states: each BDDL goal predicate read from our atoms or the scene's rules."""

from __future__ import annotations

import dataclasses

import numpy as np
from tests.symbols.test_detectors import IDX, SCENE, TABLE_Z, make_state, place, touch

from vlaprobe.symbols import Articulation, Labeler
from vlaprobe.symbols.goals import Conjunct, GoalConjunction, conjunct_value, goal_value

RULES = dataclasses.replace(
    SCENE,
    close_articulation=(Articulation(0.0, below=False, strict=True),) * 3,
    off_articulation=(Articulation(0.0, below=True, strict=True),),
)


def _values(state: object) -> dict[str, int]:
    return Labeler(RULES, None).as_dict(state)[0]  # type: ignore[arg-type]


def test_each_goal_predicate_reads_our_atom_or_the_scenes_rule() -> None:
    state = make_state(container_qpos=np.array([-0.15, -0.05, 0.01]), on_off_qpos=np.array([0.6]))
    place(state, "plate", (0.0, 0.0, TABLE_Z))
    place(state, "bowl", (0.0, 0.0, TABLE_Z + 0.01))
    touch(state, IDX["bowl"], IDX["plate"])
    top = state.region_pos[3]
    place(state, "box", (top[0], top[1], top[2] + 0.01))
    touch(state, IDX["box"], IDX["cab"])
    values = _values(state)

    def value(predicate: str, *args: str) -> bool | None:
        return conjunct_value(Conjunct(predicate, args), RULES, state, values)  # type: ignore[arg-type]

    assert value("On", "bowl", "plate") and not value("On", "plate", "bowl")
    assert value("On", "box", "cab_top_side")  # a fixture's region: on the fixture
    assert value("On", "bowl", "main_table_stove_front_region") is None  # a workspace region: no atom
    assert value("Open", "cab_top_region") and not value("Open", "cab_middle_region")
    # Close is not "not open": the middle drawer, half out, is neither open nor closed
    assert not value("Close", "cab_middle_region") and value("Close", "cab_bottom_region")
    assert value("TurnOn", "stove") and not value("TurnOff", "stove")
    assert not value("In", "bowl", "cab_top_region")


def test_the_goal_is_the_conjunction() -> None:
    state = make_state(on_off_qpos=np.array([0.6]))
    values = _values(state)
    on, stove = Conjunct("TurnOn", ("stove",)), Conjunct("On", ("bowl", "plate"))
    assert goal_value(GoalConjunction((on,)), RULES, state, values) is True
    assert goal_value(GoalConjunction((on, stove)), RULES, state, values) is False
    region = Conjunct("On", ("bowl", "main_table_stove_front_region"))
    assert goal_value(GoalConjunction((on, region)), RULES, state, values) is None
    assert goal_value(GoalConjunction((stove, region)), RULES, state, values) is False
