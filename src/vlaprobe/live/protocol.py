"""The live protocol: every message between `vlaprobe serve` and its clients, as pydantic models.

Defined once here; :func:`schema` exports them as JSON Schema into ``protocol.schema.json`` beside this file
(``python -m vlaprobe.live.protocol`` rewrites it; a test checks it is current), from which the web UI
generates its TypeScript types. docs/live.md explains the flow of messages.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Annotated, Literal

from pydantic import BaseModel, ConfigDict, Field, TypeAdapter

from vlaprobe.configs.serve import LiveDriver

SCHEMA_FILE = Path(__file__).with_name("protocol.schema.json")
PROTOCOL_VERSION = 3
"""Version of the message set, sent as ``hello.protocol``: 2 added the cognition's alarm and the takeovers
(``--takeover``); 3 the atoms an episode leaves undefined (``episode_start.defined``, their probabilities
null); a hello without the field is version 1. New fields are optional: a client of an older version reads
the messages it knows."""


class _Model(BaseModel):
    model_config = ConfigDict(extra="forbid")


# -- parts ----------------------------------------------------------------------------------------
class TaskInfo(_Model):
    index: int
    instruction: str


class HeadNames(_Model):
    """Atom names per head, in the order every per-atom list of an episode uses."""

    object: list[str]
    action: list[str]


class HeadFlags(_Model):
    object: list[bool]
    action: list[bool]


class HeadBits(_Model):
    object: list[int]
    action: list[int]


class HeadInts(_Model):
    object: int
    action: int


class ProbeInfo(_Model):
    layers: HeadInts
    """Hidden-state index each head's probe reads."""
    threshold: float
    atoms: HeadNames
    probed: HeadFlags
    """False: the atom was dropped in training; it is held at its training-majority value and never flips."""


class Running(_Model):
    episode_id: str
    paused: bool = False
    """The episode is paused (a pause command; resume or stop ends it)."""


class SubgoalInfo(_Model):
    index: int
    name: str


class SubgoalState(_Model):
    index: int
    name: str
    status: Literal["pending", "active", "done", "regressed"]


class HeadPrediction(_Model):
    values: list[int]
    """0/1 per atom."""
    probs: list[float | None]
    """Probe probability per atom; null for an atom that is not probed or is undefined in the episode
    (``episode_start.defined``)."""


class Prediction(_Model):
    object: HeadPrediction
    action: HeadPrediction


class FlipSet(_Model):
    on: list[str]
    off: list[str]


class Flips(_Model):
    predicted: FlipSet
    truth: FlipSet


class BeliefDelta(_Model):
    asserted: list[str]
    """DIARC terms newly believed at this step, e.g. ``left_of(akita_black_bowl_1,plate_1)``."""
    retracted: list[str]


class Violation(_Model):
    rule: str
    message: str
    atoms: list[str]
    since: int
    """Step at which the violation began."""


class Event(_Model):
    kind: Literal["subgoal_done", "goal_reached", "regression", "dropped", "stalled"]
    t: int
    message: str


class Alarm(_Model):
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


class Takeover(_Model):
    """One handover of the policy's control to the scripted expert (``--takeover``)."""

    index: int
    """1 for the episode's first takeover, 2 for its second, ..."""
    start: int
    """The first step whose action the expert executed."""
    reason: str
    """The alarm's ``kind: reason``, or "random" (the control)."""
    steps: int
    """Actions the expert executed in it: so far (in a step) or in all (in the episode's summary)."""


class TakeoverSettings(_Model):
    """The server's ``--takeover`` (hello.takeover)."""

    mode: Literal["alarm", "random"]
    steps: int
    """Actions the expert executes per takeover (--takeover-steps)."""
    most: int
    """Most takeovers per episode (--takeover-most)."""
    stall: int
    """Mode "alarm": the stall that fires it, in steps (--takeover-stall)."""
    hold: int
    """Mode "alarm": steps a violation must hold (--takeover-hold)."""
    count: int
    """Mode "random": takeovers per episode at random steps (--takeover-count)."""


class Timings(_Model):
    """Milliseconds spent per phase of the step (0 where a source has no such phase, e.g. replay)."""

    env_ms: float
    model_ms: float
    probes_ms: float
    cognition_ms: float
    total_ms: float
    label_ms: float = 0.0
    driver_ms: float = 0.0


class EpisodeSummary(_Model):
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


# -- server -> client -----------------------------------------------------------------------------
class Hello(_Model):
    type: Literal["hello"] = "hello"
    version: str
    suite: str = "libero_spatial"
    """The LIBERO suite of ``tasks`` and of the probes' atoms."""
    tasks: list[TaskInfo]
    model_id: str
    probes: ProbeInfo
    image_hz: float
    num_init_states: int
    drivers: list[LiveDriver]
    default_driver: LiveDriver
    running: Running | None
    protocol: int = PROTOCOL_VERSION
    """Version of the message set (absent: 1)."""
    takeover: TakeoverSettings | None = None
    """The server's --takeover (then ``drivers`` is ["policy"]); null: the driver acts alone."""


class EpisodeStart(_Model):
    type: Literal["episode_start"] = "episode_start"
    episode_id: str
    source: Literal["live", "recorded", "store"]
    suite: str = "libero_spatial"
    """The LIBERO suite of the task (recordings made before suites were recorded: LIBERO-spatial)."""
    task: int
    instruction: str
    init: int
    driver: str
    max_steps: int
    atoms: HeadNames
    probed: HeadFlags
    defined: HeadFlags | None = None
    """False for an atom undefined in this episode: over an object absent from the task's scene (a suite whose
    tasks have different objects serves the union of their atoms), or ``should-move-towards`` under a goal it
    does not follow. Such an atom is neither true nor false: its values are 0, its probability null, it is never
    asserted nor scored. Null: every atom is defined (protocol 3; before, always null)."""
    subgoals: list[SubgoalInfo]
    goal_objects: list[str] = Field(default_factory=list)
    """The objects and regions the task's goal conjunction names (``TaskGoal.objects``): the UI pins the atoms that
    mention them."""
    store_episode: str | None = None
    """Source "store": the stored episode this one re-runs (every frame at /api/episodes/{it}/frames/{t})."""
    takeover: Literal["none", "alarm", "random"] = "none"
    """Who hands the policy's control to the scripted expert in this episode (hello.takeover's mode)."""


class Step(_Model):
    type: Literal["step"] = "step"
    episode_id: str
    t: int
    image: str | None = None
    """Base64 JPEG of the upright 224x224 frame the model sees; null when dropped (slow client, --image-hz)."""
    status: str
    """The paper's client field: a status line."""
    step: int
    """The paper's client field: equals ``t``."""
    predicted: Prediction
    truth: HeadBits | None
    """Ground-truth atoms from the detectors; null where the source has none."""
    flips: Flips
    beliefs: BeliefDelta
    violations: list[Violation]
    subgoals: list[SubgoalState]
    progress: float
    events: list[Event]
    """Events of the cognition on the predictions."""
    truth_events: list[Event] = Field(default_factory=list)
    """Events of the same cognition on the ground-truth atoms (what really happened, e.g. a drop)."""
    truth_subgoals: list[SubgoalState] = Field(default_factory=list)
    """The subgoals as the same cognition sees them on the ground-truth atoms (empty without truth)."""
    truth_progress: float | None = None
    """Progress on the ground-truth atoms; null without truth."""
    perturbed: bool = False
    """A drop forced the gripper open in this step's action."""
    drop_left: int = 0
    """Steps of a requested drop still to come after this one."""
    alarm: Alarm | None = None
    """The cognition's alarm fired at this step (``--takeover alarm``): the expert acts from the next step on."""
    takeover: Takeover | None = None
    """The takeover under which the scripted expert executed this step's action; null: the episode's driver
    (the policy) acted."""
    handover: Literal["to_expert", "to_policy"] | None = None
    """"to_expert": the first step of a takeover; "to_policy": the first step the policy acts again after one
    (null on the other steps)."""
    action: list[float] | None
    """Executed action (7,); null on the terminal step."""
    predicted_action: list[float] | None
    timings: Timings
    ready_at: float = 0.0
    """Server wall clock (Unix seconds) when the message was ready to send: clients measure their lag."""


class History(_Model):
    """The episode so far, sent first to a client that joins mid-episode (steps without images)."""

    type: Literal["history"] = "history"
    episode_id: str
    start: EpisodeStart
    steps: list[Step]


class EpisodeEnd(_Model):
    type: Literal["episode_end"] = "episode_end"
    episode_id: str
    success: bool
    steps: int
    stopped: bool
    summary: EpisodeSummary


class Status(_Model):
    """Sent to every client when the running episode is paused or resumed (late joiners read hello.running)."""

    type: Literal["status"] = "status"
    episode_id: str
    paused: bool


class ErrorMessage(_Model):
    type: Literal["error"] = "error"
    message: str


# -- client -> server -----------------------------------------------------------------------------
class StartCommand(_Model):
    type: Literal["start"] = "start"
    task: int | str
    """Task index or its instruction (trimmed, any case)."""
    init: int | Literal["random"] = "random"
    driver: LiveDriver = "expert"
    max_steps: int | None = Field(default=None, ge=1, le=10_000)
    """Step budget; null: the server's (--env.max-steps). LIBERO runs at most 1000 steps per episode including
    the settling steps (990 with the default 10): a larger budget is refused with an error."""


class StopCommand(_Model):
    type: Literal["stop"] = "stop"


class PauseCommand(_Model):
    type: Literal["pause"] = "pause"


class ResumeCommand(_Model):
    type: Literal["resume"] = "resume"


class DropCommand(_Model):
    type: Literal["drop"] = "drop"
    steps: int | None = Field(default=None, ge=1, le=100)
    """Steps with the gripper forced open; null: the loop's default."""


class ReplayCommand(_Model):
    """Stream a stored episode (an id from GET /api/episodes) through the probes and the cognition."""

    type: Literal["replay"] = "replay"
    episode_id: str
    hz: float | None = Field(default=None, ge=0.5, le=60)
    """Steps per second (0.5-60); null: the server's --replay-hz."""


# -- REST -----------------------------------------------------------------------------------------
class EpisodeListItem(_Model):
    id: str
    source: Literal["live", "store"]
    task: int
    instruction: str
    init: int
    driver: str
    steps: int
    success: bool | None
    """null: the episode is running, or the server stopped before it ended."""
    stopped: bool = False
    """A client stopped it before its end (success is then false)."""
    created: str
    """ISO 8601 UTC."""


class EpisodeRecord(_Model):
    """GET /api/episodes/{id}: every step's states (no images; GET .../frames/{t} has them)."""

    start: EpisodeStart
    steps: list[Step]
    end: EpisodeEnd | None


ServerMessage = Annotated[
    Hello | EpisodeStart | Step | History | EpisodeEnd | Status | ErrorMessage, Field(discriminator="type")
]
ClientMessage = Annotated[
    StartCommand | StopCommand | PauseCommand | ResumeCommand | DropCommand | ReplayCommand,
    Field(discriminator="type"),
]
CLIENT = TypeAdapter(ClientMessage)
"""``CLIENT.validate_json(text)`` parses one client frame."""


class Protocol(_Model):
    """Every message of the live protocol."""

    server: ServerMessage
    client: ClientMessage
    episodes: list[EpisodeListItem]
    episode: EpisodeRecord


def schema() -> dict:
    """The JSON Schema of every message (what ``protocol.schema.json`` holds)."""
    return Protocol.model_json_schema()


def schema_text() -> str:
    return json.dumps(schema(), indent=2, sort_keys=True) + "\n"


if __name__ == "__main__":
    from vlaprobe.files import write_atomic

    write_atomic(SCHEMA_FILE, schema_text())
    print(SCHEMA_FILE)
