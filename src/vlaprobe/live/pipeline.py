"""From one step record to one ``step`` message: probes, flips, the cognition on predictions and on truth.

The same :class:`StepBuilder` serves live episodes, replays of stored episodes and the REST view of a store
episode, so a replay shows exactly what the live server would have shown for the same hidden states.
"""

from __future__ import annotations

import time
from collections import Counter
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import Protocol

import numpy as np

from vlaprobe.cognition.core import CognitionStep, Violation
from vlaprobe.cognition.plan import TaskGoal
from vlaprobe.cognition.subgoals import Event, SubgoalState
from vlaprobe.collection.defined import only_defined
from vlaprobe.configs.takeover import TakeoverMode
from vlaprobe.live import protocol as P
from vlaprobe.live.takeover import LiveTakeovers, TakeoverTrack, alarm_message
from vlaprobe.rollout import StepRecord, StepTimings, SuccessTracker
from vlaprobe.symbols import HEADS

STORE_PREFIX = "store-"
"""Ids of a store's episodes are ``store-<key>`` (``StoreEpisodes.PREFIX``)."""


@dataclass
class Reading:
    """One head's probe output over the episode's atoms (every atom, in vocabulary order)."""

    values: np.ndarray
    """(atoms,) bool."""
    probs: np.ndarray
    """(atoms,) float; NaN for an atom that is not probed."""
    probed: np.ndarray
    """(atoms,) bool."""


class Readout(Protocol):
    """Hidden states of one step -> a :class:`Reading` per head."""

    layers: dict[str, int]
    threshold: float
    probed: dict[str, np.ndarray]
    """Per head, (atoms,) bool: which atoms the probes read (the others are held at their training majority)."""

    def read(self, hidden: np.ndarray) -> dict[str, Reading]: ...


class EpisodeCognition(Protocol):
    """One episode's cognition (``vlaprobe.cognition.Cognition``, as ``live.serve.DiarcCognition`` spells it)."""

    @property
    def subgoals(self) -> Sequence[SubgoalState]: ...

    def step(self, object_values: np.ndarray, action_values: np.ndarray) -> CognitionStep: ...


MakeCognition = Callable[[dict[str, list[str]], TaskGoal, dict[str, np.ndarray] | None], EpisodeCognition]
"""(atoms per head, goal, probed per head or None for truth) -> a fresh cognition for one episode."""


@dataclass
class EpisodeSpec:
    """What an episode is, known before its first step."""

    task: int
    instruction: str
    init: int
    driver: str
    max_steps: int
    source: str
    """"live" or "store"."""
    suite: str
    """The LIBERO suite of the task."""
    goal: TaskGoal
    """The task's goal: its BDDL conjunction in the expert's order (``cognition.plan.task_goal``)."""
    atoms: dict[str, list[str]]
    """Atom names per head, in vocabulary order."""
    key: str = ""
    """Store episode key (store source only)."""
    takeover: TakeoverMode = "none"
    """Who hands the policy's control to the scripted expert (``serve --takeover``; live source only)."""
    seed: int = 0
    """The episode's seed (live source: it also draws the random control's takeover rows)."""
    defined: dict[str, np.ndarray] | None = None
    """Head -> bool (atoms,): the atoms defined in a stored episode of a union store (the others are never
    asserted nor scored); None: every atom."""


def _ms(timings: StepTimings | None, name: str) -> float:
    return float(getattr(timings, name)) if timings is not None else 0.0


def _floats(a: np.ndarray | None) -> list[float] | None:
    if a is None:
        return None
    a = np.asarray(a, dtype=np.float64).reshape(-1)
    return None if not np.isfinite(a).all() else [round(float(x), 5) for x in a]


def _defined(defined: dict[str, np.ndarray] | None) -> P.HeadFlags | None:
    """``episode_start.defined``: None where every atom is defined."""
    if defined is None or all(np.all(defined[h]) for h in HEADS):
        return None
    return P.HeadFlags(**{h: [bool(x) for x in defined[h]] for h in HEADS})


def _probs(probs: np.ndarray, defined: dict[str, np.ndarray] | None, head: str) -> list[float | None]:
    """Rounded probabilities; None where not probed (NaN) or undefined in the episode (``defined`` False)."""
    keep = ~np.isnan(probs) if defined is None else ~np.isnan(probs) & defined[head]
    return [round(float(p), 4) if k else None for p, k in zip(probs, keep, strict=True)]


def _violations(items: Sequence[Violation]) -> list[P.Violation]:
    return [
        P.Violation(
            rule=str(v.rule), message=str(v.message), atoms=[str(a) for a in v.atoms], since=int(v.since)
        )
        for v in items
    ]


def _events(items: Sequence[Event]) -> list[P.Event]:
    return [P.Event(kind=e.kind, t=int(e.t), message=str(e.message)) for e in items]


def _subgoals(items: Sequence[SubgoalState]) -> list[P.SubgoalState]:
    return [P.SubgoalState(index=int(g.index), name=str(g.name), status=g.status) for g in items]


def status_line(t: int, success_step: int | None, last: bool) -> str:
    """The paper's status strings (``last``: the final step of the budget)."""
    if success_step is not None:
        return f"Task completed successfully in {success_step} steps!"
    if last:
        return f"Task reached max steps ({t + 1} steps) without completion"
    return f"Executing step {t}"


@dataclass
class StepBuilder:
    """Turns the records of one episode into protocol messages and keeps the episode's summary."""

    spec: EpisodeSpec
    episode_id: str
    readout: Readout
    make_cognition: MakeCognition
    takeovers: LiveTakeovers | None = None
    """Who asks for takeovers in this episode (``serve --takeover``); None: nobody."""
    _track: TakeoverTrack = field(default_factory=TakeoverTrack)
    _prev: dict[str, np.ndarray] = field(default_factory=dict)
    _prev_truth: dict[str, np.ndarray] = field(default_factory=dict)
    _violations: Counter[str] = field(default_factory=Counter)
    _agree: list[int] = field(default_factory=lambda: [0, 0])
    goal_step_predicted: int | None = None
    goal_step_truth: int | None = None
    steps: int = 0
    success: SuccessTracker = field(default_factory=SuccessTracker)
    """The episode's success, by the loop's own rule (:class:`~vlaprobe.rollout.SuccessTracker`)."""

    def __post_init__(self) -> None:
        self._cog: EpisodeCognition | None = None
        self._cog_truth: EpisodeCognition | None = None

    def start_message(self) -> P.EpisodeStart:
        s = self.spec
        probed = {h: np.asarray(self.readout.probed[h], bool) for h in HEADS}
        subgoals = self._cognition().subgoals
        return P.EpisodeStart(
            episode_id=self.episode_id,
            source="store" if s.source == "store" else "live",
            suite=s.suite,
            task=s.task,
            instruction=s.instruction,
            init=s.init,
            driver=s.driver,
            max_steps=s.max_steps,
            atoms=P.HeadNames(object=list(s.atoms["object"]), action=list(s.atoms["action"])),
            probed=P.HeadFlags(**{h: [bool(x) for x in probed[h]] for h in HEADS}),
            defined=_defined(s.defined),
            subgoals=[P.SubgoalInfo(index=int(g.index), name=str(g.name)) for g in subgoals],
            goal_objects=s.goal.objects(),
            store_episode=f"{STORE_PREFIX}{s.key}" if s.source == "store" and s.key else None,
            takeover=s.takeover,
        )

    def _cognition(self) -> EpisodeCognition:
        if self._cog is None:
            probed = {h: np.asarray(self.readout.probed[h], bool) for h in HEADS}
            self._cog = self.make_cognition(self.spec.atoms, self.spec.goal, probed)
        return self._cog

    def step(self, rec: StepRecord) -> P.Step:
        """The ``step`` message of one record (``image`` left empty: the hub attaches images)."""
        timings = rec.timings
        t = int(rec.t)
        t0 = time.perf_counter()
        reading = self.readout.read(rec.hidden)
        t1 = time.perf_counter()
        values = only_defined({h: np.asarray(reading[h].values, bool) for h in HEADS}, self.spec.defined)
        cog = self._cognition()
        c = cog.step(values["object"], values["action"])
        alarm = None if self.takeovers is None else self.takeovers.observe(rec, c)
        taking, handover = self._track.add(rec)
        t2 = time.perf_counter()
        truth, truth_events, ct = None, [], None
        if rec.object_atoms is not None and rec.action_atoms is not None:
            truth = only_defined(
                {"object": np.asarray(rec.object_atoms, bool), "action": np.asarray(rec.action_atoms, bool)},
                self.spec.defined,
            )
            if self._cog_truth is None:
                self._cog_truth = self.make_cognition(self.spec.atoms, self.spec.goal, None)
            ct = self._cog_truth.step(truth["object"], truth["action"])
            truth_events = _events(ct.events)
            if ct.goal_reached and self.goal_step_truth is None:
                self.goal_step_truth = t
            for h in HEADS:
                probed = np.asarray(reading[h].probed, bool)
                if self.spec.defined is not None:
                    probed = probed & self.spec.defined[h]
                self._agree[0] += int((values[h] == truth[h])[probed].sum())
                self._agree[1] += int(probed.sum())
        t3 = time.perf_counter()
        if c.goal_reached and self.goal_step_predicted is None:
            self.goal_step_predicted = t
        for v in c.violations:
            if int(v.since) == t:
                self._violations[str(v.rule)] += 1
        self.steps = t + 1
        self.success.add(rec)
        msg = P.Step(
            episode_id=self.episode_id,
            t=t,
            status=status_line(t, self.success.step, bool(rec.terminal) or t == self.spec.max_steps - 1),
            step=t,
            predicted=P.Prediction(
                **{
                    h: P.HeadPrediction(
                        values=values[h].astype(int).tolist(),
                        probs=_probs(reading[h].probs, self.spec.defined, h),
                    )
                    for h in HEADS
                }
            ),
            truth=None if truth is None else P.HeadBits(**{h: truth[h].astype(int).tolist() for h in HEADS}),
            flips=P.Flips(
                predicted=self._flips(values, self._prev), truth=self._flips(truth, self._prev_truth)
            ),
            beliefs=P.BeliefDelta(asserted=list(c.asserted), retracted=list(c.retracted)),
            violations=_violations(c.violations),
            subgoals=_subgoals(c.subgoals),
            progress=float(c.progress),
            events=_events(c.events),
            truth_events=truth_events,
            truth_subgoals=[] if ct is None else _subgoals(ct.subgoals),
            truth_progress=None if ct is None else float(ct.progress),
            perturbed=bool(rec.perturbed),
            alarm=alarm_message(alarm),
            takeover=taking,
            handover=handover,
            action=_floats(rec.action),
            predicted_action=_floats(rec.predicted_action),
            timings=P.Timings(
                env_ms=_ms(timings, "env_ms"),
                label_ms=_ms(timings, "label_ms"),
                model_ms=_ms(timings, "model_ms"),
                driver_ms=_ms(timings, "driver_ms"),
                probes_ms=round((t1 - t0) * 1e3, 3),
                cognition_ms=round((t2 - t1 + time.perf_counter() - t3) * 1e3, 3),
                total_ms=round(_ms(timings, "total_ms") + (time.perf_counter() - t0) * 1e3, 3),
            ),
            ready_at=time.time(),
        )
        self._prev = values
        if truth is not None:
            self._prev_truth = truth
        return msg

    def take_request(self) -> str | None:
        """The reason of the takeover asked at the latest step, if any (the episode's control carries it)."""
        return None if self.takeovers is None else self.takeovers.take_request()

    def take_hand_back(self) -> str | None:
        """The reason of the hand-back asked at the latest step, if any (``--takeover-until subgoal``)."""
        return None if self.takeovers is None else self.takeovers.take_hand_back()

    def _flips(self, now: dict[str, np.ndarray] | None, prev: dict[str, np.ndarray]) -> P.FlipSet:
        on: list[str] = []
        off: list[str] = []
        if now is not None and prev:
            for h in HEADS:
                names = self.spec.atoms[h]
                on += [names[i] for i in np.flatnonzero(now[h] & ~prev[h])]
                off += [names[i] for i in np.flatnonzero(~now[h] & prev[h])]
        return P.FlipSet(on=on, off=off)

    def end_message(self, stopped: bool) -> P.EpisodeEnd:
        agree, total = self._agree
        return P.EpisodeEnd(
            episode_id=self.episode_id,
            success=self.success.step is not None,
            steps=self.steps,
            stopped=stopped,
            summary=P.EpisodeSummary(
                violations=dict(sorted(self._violations.items())),
                goal_step_predicted=self.goal_step_predicted,
                goal_step_truth=self.goal_step_truth,
                agreement=round(agree / total, 4) if total else 1.0,
                success_step=self.success.step,
                takeovers=[t.model_copy() for t in self._track.items],
                expert_steps=self._track.expert_steps,
            ),
        )
