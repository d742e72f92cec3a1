"""A task's goal as the cognition tracks it: the BDDL goal conjunction's conjuncts in the order the scripted
expert does them, each with its subgoals (nothing written per task).

- ``On(X, Y)`` / ``In(X, Y)``: ``should-move-towards(X)``, ``grasped(X)``, ``should-move-towards(Y')``, then the
  relation ``on(X, Y')`` / ``inside(X, Y)``; ``Y'`` is ``Y``, or the object a region ``Y`` belongs to (a drawer's
  cabinet, a basket's contain region's basket);
- ``Open(D)`` / ``Close(D)``: ``should-move-towards(D')`` (the object holding the handle), then ``open(D)`` /
  ``not(open(D))``;
- ``TurnOn(K)`` / ``TurnOff(K)``: ``should-move-towards(K)``, then ``turned-on(K)`` / ``not(turned-on(K))``.

The order of the conjuncts is that of the expert's plan (:func:`vlaprobe.experts.planner.plan_steps`: opening,
switching, placing, closing); a goal no skill handles keeps the BDDL's order. A conjunct over which our atoms say
nothing (``On`` onto a placement region of the table) is refused in one line (:func:`check_readable`); the
offline cognition leaves such episodes out, named (:func:`unreadable`).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

from vlaprobe.errors import VlaprobeError
from vlaprobe.symbols.goals import Conjunct, GoalConjunction
from vlaprobe.symbols.vocabulary import atom
from vlaprobe.symbols.world import Goal, Scene

if TYPE_CHECKING:
    from vlaprobe.collection.episode import EpisodeAttrs


@dataclass(frozen=True)
class TaskGoal:
    """The conjuncts to track, in order, and what the subgoals need of the scene."""

    conjuncts: tuple[Conjunct, ...]
    """In the expert's order."""
    parents: tuple[tuple[str, str], ...] = ()
    """(region, object it belongs to) of the scene (``Scene.region_parent``)."""
    pick_place: Goal | None = None
    """The pick-and-place goal the labeler's ``should-move-towards`` follows (one ``On`` between objects); the
    rules' ``goal(X, Y)`` fact. None for any other goal: the directive is undefined there."""

    @classmethod
    def of(cls, goal: Goal) -> TaskGoal:
        """A LIBERO-spatial pick-and-place goal."""
        return cls((Conjunct("On", (goal.pick, goal.place)),), (), goal)

    def objects(self) -> list[str]:
        """The objects and regions the conjuncts name, each followed by the object a region belongs to, in order
        (the live UI pins the atoms that mention them)."""
        parent, out = dict(self.parents), []
        for c in self.conjuncts:
            for a in c.args:
                out += [a, parent[a]] if a in parent else [a]
        return list(dict.fromkeys(out))

    def __str__(self) -> str:
        return " & ".join(map(str, self.conjuncts))


def expert_order(goal: GoalConjunction, scene: Scene) -> tuple[Conjunct, ...]:
    """The conjuncts in the order the expert's planner does them: each conjunct's own (last) step, looked up in the
    plan of the whole goal; the BDDL's order when no skill handles the goal."""
    from vlaprobe.experts.planner import plan_steps

    try:
        plan = plan_steps(goal, scene)
        own = [plan_steps(GoalConjunction((c,)), scene)[-1] for c in goal.conjuncts]
    except VlaprobeError:
        return goal.conjuncts
    order = sorted(range(len(own)), key=lambda i: plan.index(own[i]))
    return tuple(goal.conjuncts[i] for i in order)


def task_goal(goal: GoalConjunction, scene: Scene) -> TaskGoal:
    """The :class:`TaskGoal` of a task's BDDL goal in its scene."""
    pick_place = None
    if len(goal.conjuncts) == 1:
        c = goal.conjuncts[0]
        if c.predicate == "On" and c.args[0] in scene.pickupable and c.args[1] in scene.tabletop:
            pick_place = Goal(*c.args)
    return TaskGoal(expert_order(goal, scene), tuple(sorted(scene.region_parent.items())), pick_place)


def stored_task_goal(suite: str, task: int, attrs: EpisodeAttrs, where: str) -> TaskGoal:
    """The goal of a stored episode (``where`` names it in errors): its recorded pick-and-place goal, as before;
    else its task's BDDL conjunction in its stored scene."""
    if attrs.goal is not None:
        return TaskGoal.of(attrs.goal)
    if attrs.scene is None:
        raise VlaprobeError(
            f"{where} records neither a goal nor a scene; collect it again with this vlaprobe"
        )
    from vlaprobe.configs.env import SUITES
    from vlaprobe.envs.bddl_scene import task_goal as bddl_goal

    known = next((s for s in SUITES if s == suite), None)
    if known is None:
        raise VlaprobeError(f"{where} comes from an unknown suite {suite!r}; use one of {', '.join(SUITES)}")
    return task_goal(bddl_goal(known, task), attrs.scene)


@dataclass(frozen=True)
class ConjunctSubgoals:
    """One conjunct's subgoals: ``place`` (towards X, grasped X, towards Y, relation) or ``switch`` (towards,
    articulation); ``negated``: the last subgoal is its atom being false (Close, TurnOff)."""

    conjunct: Conjunct
    kind: str
    names: tuple[str, ...]
    atoms: tuple[str, ...]
    negated: bool = False


def conjunct_subgoals(c: Conjunct, goal: TaskGoal) -> ConjunctSubgoals:
    """The subgoals of one conjunct (module doc)."""
    parent = dict(goal.parents)
    p, args = c.predicate, c.args
    if p in ("On", "In"):
        x, y = args
        holder = parent.get(y, y)
        rel = atom("on", x, holder) if p == "On" else atom("inside", x, y)
        names = (atom("should-move-towards", x), atom("grasped", x), atom("should-move-towards", holder), rel)
        return ConjunctSubgoals(c, "place", names, names)
    pred = "open" if p in ("Open", "Close") else "turned-on"
    thing = args[0]
    towards = atom("should-move-towards", parent.get(thing, thing))
    negated = p in ("Close", "TurnOff")
    last = atom(pred, thing)
    return ConjunctSubgoals(
        c, "switch", (towards, f"not({last})" if negated else last), (towards, last), negated
    )


def unreadable(goal: TaskGoal, atoms: set[str] | dict[str, int] | tuple[str, ...]) -> str | None:
    """Why the cognition cannot follow ``goal`` over ``atoms`` (a subgoal's atom is missing), or None."""
    for part in (conjunct_subgoals(c, goal) for c in goal.conjuncts):
        missing = [a for a in part.atoms if a not in atoms]
        if missing:
            return (
                f"the goal {part.conjunct} needs the atom {missing[0]!r}, which is not among the atoms given "
                "(a goal onto a placement region of the table has none)"
            )
    return None


def check_readable(goal: TaskGoal, atoms: set[str] | dict[str, int]) -> None:
    """Every subgoal's atom is among the cognition's atoms; else one line naming the conjunct."""
    problem = unreadable(goal, atoms)
    if problem is not None:
        raise VlaprobeError(
            f"{problem}; pass the task's full object and action atoms, or leave the task out (--tasks)"
        )
