"""The parts the live protocol's messages (:mod:`vlaprobe.live.protocol`) are made of, as pydantic models.

Clients read them as ``vlaprobe.live.protocol``'s names (each is importable from there); the JSON Schema of
every message, parts included, is exported from there.
"""

from __future__ import annotations

from typing import Literal

from pydantic import BaseModel, ConfigDict, Field

from vlaprobe.configs.takeover import ALARM_KINDS, AlarmKind


class StrictModel(BaseModel):
    """A message part: unknown fields are refused."""

    model_config = ConfigDict(extra="forbid")


# -- parts ----------------------------------------------------------------------------------------
class TaskInfo(StrictModel):
    index: int
    instruction: str


class HeadNames(StrictModel):
    """Atom names per head, in the order every per-atom list of an episode uses."""

    object: list[str]
    action: list[str]


class HeadFlags(StrictModel):
    object: list[bool]
    action: list[bool]


class HeadBits(StrictModel):
    """0/1 per atom, in ``episode_start.atoms`` order. An atom the episode leaves undefined
    (``episode_start.defined`` false) is sent as 0: a placeholder, not false."""

    object: list[int]
    action: list[int]


class HeadInts(StrictModel):
    object: int
    action: int


class ProbeInfo(StrictModel):
    layers: HeadInts
    """Hidden-state index each head's probe reads."""
    threshold: float
    atoms: HeadNames
    probed: HeadFlags
    """False: the atom was dropped in training; it is held at its training-majority value and never flips."""


class Running(StrictModel):
    episode_id: str
    paused: bool = False
    """The episode is paused (a pause command; resume or stop ends it)."""


class SubgoalInfo(StrictModel):
    index: int
    name: str


class SubgoalState(StrictModel):
    index: int
    name: str
    status: Literal["pending", "active", "done", "regressed"]


class HeadPrediction(StrictModel):
    values: list[int]
    """0/1 per atom; 0 also for an atom undefined in the episode (``episode_start.defined`` false), which a client
    must not read as false."""
    probs: list[float | None]
    """Probe probability per atom; null for an atom that is not probed or is undefined in the episode
    (``episode_start.defined``)."""


class Prediction(StrictModel):
    object: HeadPrediction
    action: HeadPrediction


class FlipSet(StrictModel):
    on: list[str]
    off: list[str]


class Flips(StrictModel):
    predicted: FlipSet
    truth: FlipSet


class BeliefDelta(StrictModel):
    asserted: list[str]
    """DIARC terms newly believed at this step, e.g. ``left_of(akita_black_bowl_1,plate_1)``."""
    retracted: list[str]


class Violation(StrictModel):
    rule: str
    message: str
    atoms: list[str]
    since: int
    """Step at which the violation began."""


class Event(StrictModel):
    kind: Literal["subgoal_done", "goal_reached", "regression", "dropped", "stalled"]
    t: int
    message: str


class Alarm(StrictModel):
    """The cognition's alarm (``--takeover alarm``), read on the predictions: why it fired."""

    kind: Literal["stall", "regression", "dropped", "violation"]
    """"stall": no subgoal done for --takeover-stall steps; "regression", "dropped": the cognition's event;
    "violation": a consistency rule's violation held --takeover-hold steps."""
    reason: str
    """One line, e.g. "no subgoal done for 40 steps (next: grasp akita_black_bowl_1)"."""
    rules: list[str]
    """The rules whose violations drove it (kind "violation")."""
    atoms: list[str]
    """The beliefs involved: the violations' atoms, or the stalled subgoal."""


class Takeover(StrictModel):
    """One handover of the policy's control to the scripted expert (``--takeover``)."""

    index: int
    """1 for the episode's first takeover, 2 for its second, ..."""
    start: int
    """The first step whose action the expert executed."""
    reason: str
    """The alarm's ``kind: reason``, or "random" (the control)."""
    steps: int
    """Actions the expert executed in it: so far (in a step) or in all (in the episode's summary)."""
    ended: str | None = None
    """Why the expert handed back: "subgoal: NAME" (the subgoal current at its start is done, hello.takeover.until
    "subgoal"), "goal" (the goal holds), "cap" (its steps ran out under "subgoal"), "steps" (its fixed length
    under "steps"); null while it acts, or when the episode ended first (protocol 4)."""


class TakeoverSettings(StrictModel):
    """The server's ``--takeover`` (hello.takeover)."""

    mode: Literal["alarm", "random"]
    steps: int
    """Actions the expert executes per takeover (--takeover-steps): at most (until "subgoal"), or exactly."""
    until: Literal["subgoal", "steps"] = "steps"
    """When the expert hands back (--takeover-until): once the subgoal current at the takeover's start is done
    (or the goal holds), or after ``steps`` actions; absent (protocol 3 and before): "steps"."""
    most: int
    """Most takeovers per episode (--takeover-most)."""
    stall: int
    """Mode "alarm": the stall that fires it, in steps (--takeover-stall)."""
    hold: int
    """Mode "alarm": steps a violation must hold (--takeover-hold)."""
    on: list[AlarmKind] = Field(default_factory=lambda: list(ALARM_KINDS))
    """Mode "alarm": what fires it (--takeover-on); absent (protocol 4 and before): all four."""
    count: int
    """Mode "random": takeovers per episode at random steps (--takeover-count)."""


class Timings(StrictModel):
    """Milliseconds spent per phase of the step (0 where a source has no such phase, e.g. replay)."""

    env_ms: float
    model_ms: float
    probes_ms: float
    cognition_ms: float
    total_ms: float
    label_ms: float = 0.0
    driver_ms: float = 0.0


class EpisodeSummary(StrictModel):
    violations: dict[str, int]
    """Rule id -> number of violations that began during the episode (from the predictions)."""
    goal_step_predicted: int | None
    goal_step_truth: int | None
    agreement: float
    """Share of (step, probed atom) pairs where the prediction equals the truth (1.0 without truth)."""
    success_step: int | None = None
    """First step at which the task's own success check held (``steps`` also counts the rows after it)."""
    takeovers: list[Takeover] = Field(default_factory=list)
    """The episode's takeovers (``--takeover``), each with its total ``steps``."""
    expert_steps: int = 0
    """Actions the scripted expert executed in takeovers."""
