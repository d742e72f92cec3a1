"""A task's goal as typed data: the conjunction of LIBERO's BDDL ``:goal`` (On, In, Open, Close, TurnOn, TurnOff).

The BDDL spells the predicates ``On``, ``In``, ``Open``, ``Close``, ``Turnon``, ``Turnoff`` (any case);
:func:`goal_predicate` maps each to one :data:`GoalPredicate`. Arguments are the BDDL's names: objects,
fixtures, or regions (``wooden_cabinet_1_top_region``, ``main_table_stove_front_region``).
"""

from __future__ import annotations

import typing
from dataclasses import dataclass
from typing import Literal

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
