"""Goal and subgoals of a task, tracked over the beliefs of each step.

The goal's conjuncts, in the expert's order, each with its subgoals (:mod:`vlaprobe.cognition.plan`); a conjunct's
subgoals count once those of the conjuncts before it are all done. A ``switch`` conjunct (Open, Close, TurnOn,
TurnOff) has two: ``should-move-towards(D)``, done once believed and ended (or once the articulation holds), then
the articulation. A ``place`` conjunct (``On(X, Y)``, ``In(X, Y)``) has four:

1. ``should-move-towards(X)``: done once that directive has been believed and has ended, or X is grasped;
2. ``grasped(X)``: done while X is grasped (or placed);
3. ``should-move-towards(Y)``: done once that directive has ended while X is still grasped, or X is on Y;
4. ``on(X,Y)`` (``inside(X,Y)``): the relation; done while it holds after X was grasped and is no longer grasped (an ``on``
   believed during the carry, or before any grasp, is not the goal: the rules report the first as
   ``on_while_grasped``).

X let go while ``should-move-towards(Y)`` still holds is still on its way (settling on Y, or falling).
The *level* is the number of subgoals done; they are done in order, so a step may complete several. When the
beliefs have supported a lower level for ``regression_steps`` consecutive steps, the subgoals in between are
*regressed* (undone; to be done again) and a ``regression`` event is raised, with "dropped" when X was grasped
and is now neither grasped nor on Y. The wait is needed because a placing hand lets go above the place: the
scripted expert opens the gripper 2-3 steps before X rests on Y. With no new subgoal done for ``stall_steps``
steps before the goal, one ``stalled`` event (again after progress). For goals other than one pick-and-place
the labeler leaves ``should-move-towards`` undefined (all false): a towards subgoal is then done with the subgoal
after it, and the relation counts once X has been grasped at any time of the episode. When ``grasped(X)`` is
*unknown* (probes without an action head: no belief about it carries information), the relation alone marks the
four subgoals done.
"""

from __future__ import annotations

from collections.abc import Collection, Mapping
from dataclasses import dataclass
from typing import Literal

import numpy as np

from vlaprobe.cognition.plan import ConjunctSubgoals, TaskGoal, check_readable, conjunct_subgoals
from vlaprobe.errors import VlaprobeError
from vlaprobe.symbols.world import Goal

Status = Literal["pending", "active", "done", "regressed"]
EventKind = Literal["subgoal_done", "goal_reached", "regression", "dropped", "stalled"]


@dataclass(frozen=True)
class SubgoalState:
    """One subgoal's status at one step."""

    index: int
    """1..N, in the order the subgoals must be done."""
    name: str
    """The belief that marks it, e.g. ``"should-move-towards(akita_black_bowl_1)"``."""
    status: Status
    """``done``; ``active`` (the next to do); ``regressed`` (was done, undone since); ``pending``."""


@dataclass(frozen=True)
class Event:
    """Something that happened to the task's progress at one step."""

    kind: EventKind
    t: int
    """Step at which it happened (the step whose beliefs show it)."""
    message: str
    """One line for people."""


class _Place:
    """Support of a place conjunct's four subgoals (module doc)."""

    def __init__(self, part: ConjunctSubgoals, index: Mapping[str, int], directed: bool, blind: bool) -> None:
        self.part, self.n, self.directed, self.blind = part, 4, directed, blind
        self._i = tuple(index[a] for a in part.atoms)
        self.reset()

    def reset(self) -> None:
        self._seen_towards = [False, False]  # directive believed since its subgoal became the next to do
        self._seen_grasp = False  # X grasped since the start (or since a regression below subgoal 2)

    def support(self, b: np.ndarray, level: int) -> int:
        """Highest level the current beliefs (and the directives seen) support; ``level``: the one reached."""
        towards_x, grasped, towards_y, on = (bool(b[i]) for i in self._i)
        if self.blind:  # grasped(X) unknown: the relation is all there is to see
            return 4 if on else 0
        if grasped:
            self._seen_grasp = True
        elif on and self._seen_grasp:
            return 4
        if grasped:
            if level >= 2 and towards_y:
                self._seen_towards[1] = True
            return 3 if self._seen_towards[1] and not towards_y else 2
        if towards_y and level >= 2:
            return level  # let go, still on its way to Y (settling on it, or falling)
        self._seen_towards[1] = False
        if towards_x:
            self._seen_towards[0] = True
        return 1 if self._seen_towards[0] and not towards_x else 0

    def regressed(self, new: int) -> None:
        if new == 0:
            self._seen_towards[0] = False
        if new < 2 and self.directed:  # without the directive a release cannot be told from a drop
            self._seen_grasp = False


class _Switch:
    """Support of a switch conjunct's two subgoals (module doc)."""

    def __init__(self, part: ConjunctSubgoals, index: Mapping[str, int], directed: bool, blind: bool) -> None:
        self.part, self.n = part, 2
        self._i = tuple(index[a] for a in part.atoms)
        self.reset()

    def reset(self) -> None:
        self._seen = False

    def support(self, b: np.ndarray, level: int) -> int:
        towards, value = (bool(b[i]) for i in self._i)
        if value != self.part.negated:
            return 2
        self._seen |= towards
        return 1 if self._seen and not towards else 0

    def regressed(self, new: int) -> None:
        if new == 0:
            self._seen = False


class SubgoalTracker:
    """Level of a task's subgoals from the beliefs of each step."""

    def __init__(
        self,
        index: Mapping[str, int],
        goal: Goal | TaskGoal,
        stall_steps: int = 150,
        regression_steps: int = 8,
        unknown: Collection[str] = (),
    ) -> None:
        """``unknown``: atoms whose beliefs carry no information (a head without probes)."""
        self.goal = goal if isinstance(goal, TaskGoal) else TaskGoal.of(goal)
        check_readable(self.goal, dict(index))
        parts = tuple(conjunct_subgoals(c, self.goal) for c in self.goal.conjuncts)
        if stall_steps < 1 or regression_steps < 1:
            raise VlaprobeError(
                f"stall_steps and regression_steps must be at least 1, got {stall_steps} and {regression_steps}"
            )
        directed = self.goal.pick_place is not None  # the labeler defines should-move-towards for this goal
        unknown = set(unknown)
        self._parts = [
            (_Place if p.kind == "place" else _Switch)(p, index, directed, p.atoms[1] in unknown)
            for p in parts
        ]
        self.names = tuple(n for p in parts for n in p.names)
        self._offsets = np.cumsum([0] + [p.n for p in self._parts]).tolist()
        self.total = len(self.names)
        self._relations = " & ".join(p.names[-1] for p in parts)
        self.stall_steps = int(stall_steps)
        self.regression_steps = int(regression_steps)
        self.reset()

    def reset(self) -> None:
        self.level = 0
        self._regressed = [False] * self.total
        for part in self._parts:
            part.reset()
        self._last_progress = 0
        self._below = 0  # consecutive steps the beliefs have supported less than the level
        self._stalled = False
        self._states: tuple[SubgoalState, ...] | None = None

    def _own(self, k: int, level: int) -> int:
        """Conjunct ``k``'s share of an overall ``level``."""
        return min(max(level - self._offsets[k], 0), self._parts[k].n)

    def _support(self, b: np.ndarray) -> int:
        """Highest overall level the beliefs support: the conjuncts' own levels, each counted once those before
        it are done (every conjunct's support is updated at every step: it remembers what it saw)."""
        own = [p.support(b, self._own(k, self.level)) for k, p in enumerate(self._parts)]
        level = 0
        for part, s in zip(self._parts, own, strict=True):
            level += s
            if s < part.n:
                break
        return level

    def update(self, t: int, beliefs: np.ndarray) -> list[Event]:
        """Advance to step ``t``; the events of this step, in order."""
        old, new = self.level, self._support(beliefs)
        self._below = self._below + 1 if new < old else 0
        if new < old and self._below < self.regression_steps:
            new = old  # not (yet) a regression: wait whether it lasts
        events: list[Event] = []
        if new > old:
            for k in range(old, new):
                self._regressed[k] = False
                events.append(Event("subgoal_done", t, f"subgoal {k + 1} done: {self.names[k]}"))
            if new == self.total:
                events.append(Event("goal_reached", t, f"goal reached: {self._relations}"))
            self._last_progress, self._stalled = t, False
        elif new < old:
            self._below = 0
            for k in range(new, old):
                self._regressed[k] = True
            undone = ", ".join(self.names[new:old])
            events.append(Event("regression", t, f"regression: {undone} no longer done"))
            for k, part in enumerate(self._parts):
                was, now = self._own(k, old), self._own(k, new)
                if now < was:
                    part.regressed(now)
                if isinstance(part, _Place) and was in (2, 3) and now < 2:
                    x, y = part.part.conjunct.args
                    rel = "on" if part.part.conjunct.predicate == "On" else "inside"
                    message = f"dropped: {x} was grasped, is now neither grasped nor {rel} {y}"
                    events.append(Event("dropped", t, message))
            self._last_progress, self._stalled = t, False
        elif new < self.total and not self._stalled and t - self._last_progress >= self.stall_steps:
            self._stalled = True
            events.append(
                Event("stalled", t, f"stalled: no subgoal done for {t - self._last_progress} steps")
            )
        if new != old:
            self._states = None
        self.level = new
        return events

    @property
    def done(self) -> bool:
        """Whether every subgoal is done (the goal holds)."""
        return self.level == self.total

    @property
    def active(self) -> int:
        """Index (1..N) of the next subgoal to do; N + 1 once all are done."""
        return self.level + 1

    @property
    def progress(self) -> float:
        return self.level / self.total

    def states(self) -> tuple[SubgoalState, ...]:
        if self._states is None:
            out = []
            for k, name in enumerate(self.names):
                if k < self.level:
                    status: Status = "done"
                elif self._regressed[k]:
                    status = "regressed"
                else:
                    status = "active" if k == self.level else "pending"
                out.append(SubgoalState(k + 1, name, status))
            self._states = tuple(out)
        return self._states
