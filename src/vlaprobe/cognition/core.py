"""One call per step: truth values in, beliefs, violations, subgoals and events out.

    cog = Cognition(vocab.object_atoms, vocab.action_atoms, Goal("akita_black_bowl_1", "plate_1"))
    for obj, act in steps:                         # bool arrays in atom order, from probes, detectors or a store
        cs = cog.step(obj, act)
        cs.violations, cs.subgoals, cs.events       # typed; see CognitionStep

The pipeline of a step: input -> debounced beliefs (:class:`BeliefStore`) -> rules (:class:`RuleEngine`, clingo)
and subgoals (:class:`SubgoalTracker`). Atoms marked not probed keep their step-0 value and never flip.
"""

from __future__ import annotations

from collections.abc import Collection, Mapping, Sequence
from dataclasses import dataclass

import numpy as np

from vlaprobe.cognition.beliefs import BeliefStore
from vlaprobe.cognition.plan import TaskGoal
from vlaprobe.cognition.solver import RuleEngine, RuleHit
from vlaprobe.cognition.subgoals import Event, SubgoalState, SubgoalTracker
from vlaprobe.configs.monitor import CognitionConfig
from vlaprobe.errors import VlaprobeError
from vlaprobe.symbols.world import Goal


@dataclass(frozen=True)
class Violation:
    """An inconsistency among the current beliefs, found by one rule."""

    rule: str
    """Rule id, e.g. ``"on_and_inside"``."""
    message: str
    """One line: the rule's message and the atoms."""
    atoms: tuple[str, ...]
    """The beliefs involved, canonical spelling."""
    since: int
    """First step of the current run of steps during which it has held."""


@dataclass(frozen=True)
class CognitionStep:
    """Everything the cognition concluded at one step."""

    t: int
    """Step index since the last reset (0 first)."""
    asserted: tuple[str, ...]
    """Beliefs that became true at this step (at step 0: every true one), canonical spelling."""
    retracted: tuple[str, ...]
    """Beliefs that became false at this step."""
    violations: tuple[Violation, ...]
    """Every violation that holds now."""
    subgoals: tuple[SubgoalState, ...]
    """Every subgoal's state (four per pick-and-place conjunct, two per switch; ``vlaprobe.cognition.plan``)."""
    progress: float
    """Share of subgoals done, 0..1."""
    events: tuple[Event, ...]
    """Events new at this step."""
    goal_reached: bool
    """Whether the goal holds now (all subgoals done)."""


class Cognition:
    """Belief store, consistency rules and subgoal tracking for one task's atoms."""

    def __init__(
        self,
        object_atoms: Sequence[str],
        action_atoms: Sequence[str],
        goal: Goal | TaskGoal,
        config: CognitionConfig | None = None,
        probed: Mapping[str, np.ndarray] | None = None,
        unknown: Collection[str] = (),
    ) -> None:
        """``probed``: per head, which atoms a probe predicts (the others keep their step-0 value); ``unknown``:
        atoms whose values carry no information at all (a head without probes), which the subgoals do not wait
        for (:class:`SubgoalTracker`)."""
        self.config = config or CognitionConfig()
        self.object_atoms = tuple(object_atoms)
        self.action_atoms = tuple(action_atoms)
        self.atoms = self.object_atoms + self.action_atoms
        self.goal = goal if isinstance(goal, TaskGoal) else TaskGoal.of(goal)
        fixed = None
        if probed is not None:
            masks = []
            for head, atoms in (("object", self.object_atoms), ("action", self.action_atoms)):
                m = np.asarray(probed.get(head, np.ones(len(atoms), bool)), dtype=bool)
                if m.shape != (len(atoms),):
                    raise VlaprobeError(
                        f"probed[{head!r}] must have one entry per {head} atom ({len(atoms)})"
                    )
                masks.append(m)
            fixed = ~np.concatenate(masks)
        self.beliefs = BeliefStore(self.atoms, self.config.debounce, fixed)
        self.rules = RuleEngine(
            self.atoms,
            goal,
            self.config.rules,
            self.config.shipped_rules,
            self.config.recent_steps,
            self.config.budget,
        )
        self.subgoals = SubgoalTracker(
            self.beliefs.index, goal, self.config.stall_steps, self.config.regression_steps, unknown
        )
        self.reset()

    def reset(self) -> None:
        """Start a new episode: empty history, subgoals from the start."""
        self.beliefs.reset()
        self.rules.reset()
        self.subgoals.reset()
        self._hits: list[RuleHit] | None = None
        self._since: dict[tuple[str, str], int] = {}
        self._violations: tuple[Violation, ...] = ()

    def step(self, object_values: np.ndarray, action_values: np.ndarray) -> CognitionStep:
        """Feed one step's truth values (bool, atom order) and get the cognition's conclusions."""
        obj = np.asarray(object_values, dtype=bool).reshape(-1)
        act = np.asarray(action_values, dtype=bool).reshape(-1)
        if obj.shape[0] != len(self.object_atoms) or act.shape[0] != len(self.action_atoms):
            raise VlaprobeError(
                f"expected {len(self.object_atoms)} object and {len(self.action_atoms)} action values, got "
                f"{obj.shape[0]} and {act.shape[0]}; pass them in the atom order the cognition was built with"
            )
        store = self.beliefs
        up, down = store.update(np.concatenate([obj, act]))
        t = store.t
        hits = self.rules.evaluate(t, store.values, up, down)
        if hits is not self._hits:
            self._hits = hits
            self._violations = self._track(t, hits)
        events = self.subgoals.update(t, store.values)
        atoms = self.atoms
        return CognitionStep(
            t=t,
            asserted=tuple(atoms[i] for i in up.tolist()),
            retracted=tuple(atoms[i] for i in down.tolist()),
            violations=self._violations,
            subgoals=self.subgoals.states(),
            progress=self.subgoals.progress,
            events=tuple(events),
            goal_reached=self.subgoals.done,
        )

    def _track(self, t: int, hits: list[RuleHit]) -> tuple[Violation, ...]:
        since = {(h.rule, h.key): self._since.get((h.rule, h.key), t) for h in hits}
        self._since = since
        messages = self.rules.messages
        return tuple(
            Violation(
                rule=h.rule,
                message=f"{messages.get(h.rule, h.rule)}: {', '.join(h.atoms)}"
                if h.atoms
                else messages.get(h.rule, h.rule),
                atoms=h.atoms,
                since=since[h.rule, h.key],
            )
            for h in hits
        )
