"""Which episodes to run and which to keep, so that the result never depends on workers or interruptions.

The serial rule defines the result: for each task, try init states 0, 1, 2, ... (attempt 0 each) in order,
stop after ``per_task`` successes or when the try budget (init states ``0..budget-1``) is spent (with ``first``,
the init states ``first..first+budget-1``: the ones before are held out, e.g. for a closed-loop evaluation). A unit's
outcome depends only on (task, init) (fixed init state, seed derived from it), so the set of tried units —
the *serial prefix* of each task — is a function of the outcomes alone.

With several workers, units finish out of order. A finished unit ``i`` is kept (published) once it is
certainly in the prefix: even if every unresolved earlier init succeeded, fewer than ``per_task`` successes
would precede it. It is dropped once ``per_task`` known successes precede it. Until then it is held.
Launching follows the same test: a unit is *needed* when it would be in the prefix even if every running
earlier unit succeeded; idle workers may also *speculate* on the next unit of a task (it may end up dropped).
A resume starts from the outcomes already in the store, so interrupted, resumed, serial and parallel runs all
end with the same kept units.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field

from vlaprobe.collection.store import episode_key


@dataclass(frozen=True, order=True)
class Unit:
    """One episode to run: a task, one of its fixed init states, an attempt number."""

    task: int
    init: int
    attempt: int = 0

    @property
    def key(self) -> str:
        return episode_key(self.task, self.init, self.attempt)


@dataclass(frozen=True)
class Affinity:
    """Which simulators the workers hold. Building one takes seconds (LIBERO: ~2-3 s), so the worker that takes
    the next unit keeps to its own task, and otherwise starts a task no other worker holds."""

    own: int | None = None
    """The task whose simulator the worker that takes the next unit holds (None: none yet)."""
    others: frozenset[int] = frozenset()
    """The tasks whose simulators the other workers hold."""

    def rank(self, task: int) -> int:
        """0 for the worker's own task, 1 for a task no worker holds, 2 for another worker's task."""
        return 0 if task == self.own else 2 if task in self.others else 1


@dataclass
class _Task:
    outcome: dict[int, bool] = field(default_factory=dict)  # init -> success, for every finished/stored unit
    running: set[int] = field(default_factory=set)
    held: set[int] = field(default_factory=set)  # finished this run, not yet kept or dropped
    kept: set[int] = field(default_factory=set)  # in the prefix: stored before or kept this run


class Plan:
    """The deterministic schedule of a collection run (pure bookkeeping: no simulator, no store)."""

    def __init__(
        self,
        tasks: Sequence[int],
        per_task: int,
        budget: int,
        known: Mapping[tuple[int, int], bool],
        first: int = 0,
    ) -> None:
        """``known``: (task, init) -> success of the units the store already holds (episodes and failure marks).
        ``first``: the first init state tried; the budget counts from it."""
        self.tasks = list(tasks)
        self.per_task = per_task
        self.budget = budget
        self.first = first
        self._t = {t: _Task() for t in self.tasks}
        for (t, i), success in known.items():
            if t in self._t and first <= i < first + budget:
                self._t[t].outcome[i] = success
        for t in self.tasks:
            self._t[t].kept = {i for i in self._t[t].outcome if self._status(t, i) == "in"}

    # ----- the rule --------------------------------------------------------------------------------------------
    def _before(self, t: int, i: int) -> tuple[int, int]:
        """(known successes, unresolved units) among init states first..i-1 of task t."""
        outcome = self._t[t].outcome
        successes = sum(1 for j, ok in outcome.items() if j < i and ok)
        unresolved = sum(1 for j in range(self.first, i) if j not in outcome)
        return successes, unresolved

    def _status(self, t: int, i: int) -> str:
        """'in' / 'out' of task t's serial prefix, or 'open' while earlier outcomes could still decide it."""
        successes, unresolved = self._before(t, i)
        if successes >= self.per_task or not self.first <= i < self.first + self.budget:
            return "out"
        return "in" if successes + unresolved < self.per_task else "open"

    def _candidate(self, t: int) -> int | None:
        """The lowest init state of task t not yet run, running or stored; None when there is nothing to try."""
        s = self._t[t]
        span = range(self.first, self.first + self.budget)
        i = next((i for i in span if i not in s.outcome and i not in s.running), None)
        return i if i is not None and self._status(t, i) != "out" else None

    # ----- driving it ------------------------------------------------------------------------------------------
    def next_unit(self, speculate: bool = False, affinity: Affinity | None = None) -> Unit | None:
        """The next unit to launch: a needed one, else with ``speculate`` a guess, else None. Among them the
        ``affinity`` order (the worker's own task, then a task no worker holds), then the lowest task. The
        order changes only when a unit runs, never which units are kept."""
        rank = (affinity or Affinity()).rank
        needed, guesses = [], []
        for t in self.tasks:
            i = self._candidate(t)
            if i is None:
                continue
            if self._status(t, i) == "in":
                needed.append((rank(t), t, i))
            else:
                guesses.append((len(self._t[t].running), rank(t), t, i))
        if needed:
            _, t, i = min(needed)
            return Unit(t, i)
        if speculate and guesses:
            *_, t, i = min(guesses)
            return Unit(t, i)
        return None

    def started(self, unit: Unit) -> None:
        self._t[unit.task].running.add(unit.init)

    def finished(self, unit: Unit, success: bool) -> list[tuple[Unit, bool]]:
        """Record an outcome; returns the held units of that task now decided: (unit, keep)."""
        s = self._t[unit.task]
        s.running.discard(unit.init)
        s.outcome[unit.init] = success
        s.held.add(unit.init)
        decided = []
        for i in sorted(s.held):
            status = self._status(unit.task, i)
            if status != "open":
                s.held.discard(i)
                if status == "in":
                    s.kept.add(i)
                decided.append((Unit(unit.task, i), status == "in"))
        return decided

    def complete(self) -> bool:
        """Every task's prefix is fully known and decided (running units, if any, are beyond it)."""
        return all(self._candidate(t) is None and self._open_units(t) == 0 for t in self.tasks)

    def _open_units(self, t: int) -> int:
        """Units of task t that are running or held and could still be in its prefix."""
        s = self._t[t]
        return sum(1 for i in s.running | s.held if self._status(t, i) != "out")

    # ----- reporting -------------------------------------------------------------------------------------------
    def kept(self, t: int) -> tuple[int, int]:
        """(successes, tries) among the units of task t kept so far."""
        s = self._t[t]
        return sum(1 for i in s.kept if s.outcome[i]), len(s.kept)

    def exhausted(self, t: int) -> bool:
        """The try budget of task t is spent with fewer than ``per_task`` successes."""
        successes, tries = self.kept(t)
        return successes < self.per_task and tries >= self.budget
