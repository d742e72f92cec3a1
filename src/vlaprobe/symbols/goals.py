"""A task's goal as typed data: the conjunction of LIBERO's BDDL ``:goal`` (On, In, Open, Close, TurnOn, TurnOff).

The BDDL spells the predicates ``On``, ``In``, ``Open``, ``Close``, ``Turnon``, ``Turnoff`` (any case);
:func:`goal_predicate` maps each to one :data:`GoalPredicate`. Arguments are the BDDL's names: objects,
fixtures, or regions (``wooden_cabinet_1_top_region``, ``main_table_stove_front_region``).
"""

from __future__ import annotations

import typing
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Literal

import numpy as np

from vlaprobe.symbols.vocabulary import atom
from vlaprobe.symbols.world import Scene, WorldState

GoalPredicate = Literal["On", "In", "Open", "Close", "TurnOn", "TurnOff"]
GOAL_PREDICATES: tuple[GoalPredicate, ...] = typing.get_args(GoalPredicate)
ARITY: dict[GoalPredicate, int] = {"On": 2, "In": 2, "Open": 1, "Close": 1, "TurnOn": 1, "TurnOff": 1}
_BY_LOWER: dict[str, GoalPredicate] = {p.lower(): p for p in GOAL_PREDICATES}


def goal_predicate(word: str) -> GoalPredicate:
    """The goal predicate a BDDL word names (``"turnon"`` -> ``"TurnOn"``); ValueError for any other word."""
    try:
        return _BY_LOWER[word.lower()]
    except KeyError:
        raise ValueError(f"{word!r} is not a goal predicate; expected one of {GOAL_PREDICATES}") from None


@dataclass(frozen=True)
class Conjunct:
    """One conjunct of a goal, e.g. ``Conjunct("In", ("akita_black_bowl_1", "wooden_cabinet_1_top_region"))``."""

    predicate: GoalPredicate
    args: tuple[str, ...]

    def __post_init__(self) -> None:
        if len(self.args) != ARITY[self.predicate]:
            raise ValueError(f"{self.predicate} takes {ARITY[self.predicate]} argument(s), got {self.args}")

    def __str__(self) -> str:
        return f"{self.predicate}({','.join(self.args)})"


@dataclass(frozen=True)
class GoalConjunction:
    """A task's goal: every conjunct must hold (BDDL ``(:goal (And ...))``), in the BDDL's order."""

    conjuncts: tuple[Conjunct, ...]

    def __str__(self) -> str:
        return " & ".join(str(c) for c in self.conjuncts)

    @property
    def names(self) -> frozenset[str]:
        """Every object, fixture or region the goal mentions."""
        return frozenset(a for c in self.conjuncts for a in c.args)


def conjunct_value(
    conjunct: Conjunct, scene: Scene, state: WorldState, values: Mapping[str, int | bool]
) -> bool | None:
    """Our detectors' value of one goal (or BDDL ``:init``) conjunct: ``values`` are the object atoms of the same
    step (name -> 0/1). ``On(a, b)`` is ``on(a, b)`` for an object ``b``, ``on(a, fixture)`` for a region of a
    fixture (its top, its cook region); ``In`` is ``inside``; ``Open`` is ``open``; ``TurnOn`` is ``turned-on``;
    ``Close`` and ``TurnOff`` apply the scene's own rules (not the negations: a drawer half out is neither).
    None where no atom of ours covers it: ``On`` onto a region of the workspace (the vocabulary has no atom
    over the table's placement regions, e.g. ``main_table_stove_front_region``)."""
    p, args = conjunct.predicate, conjunct.args
    if p == "On":
        a, b = args
        if b in scene.tabletop:
            return bool(values[atom("on", a, b)])
        parent = scene.region_parent.get(b)
        return None if parent is None else bool(values[atom("on", a, parent)])
    if p == "In":
        return bool(values[atom("inside", *args)])
    if p == "Open":
        return bool(values[atom("open", args[0])])
    if p == "TurnOn":
        return bool(values[atom("turned-on", args[0])])
    if p == "Close":
        i = scene.openable.index(args[0])
        return bool(scene.close_articulation[i].is_active(np.asarray(state.container_qpos[i])))
    i = scene.on_off.index(args[0])  # TurnOff
    return bool(scene.off_articulation[i].is_active(np.asarray(state.on_off_qpos[i])))


def goal_value(
    goal: GoalConjunction, scene: Scene, state: WorldState, values: Mapping[str, int | bool]
) -> bool | None:
    """Our goal: every conjunct holds (None when one is not covered by our atoms and the others hold)."""
    out: bool | None = True
    for c in goal.conjuncts:
        v = conjunct_value(c, scene, state, values)
        if v is False:
            return False
        if v is None:
            out = None
    return out
