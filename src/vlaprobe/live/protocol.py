"""The live protocol: every message between `vlaprobe serve` and its clients, as pydantic models.

Defined once here (the parts they are made of in :mod:`vlaprobe.live.protocol_parts`); :func:`schema`
exports them as JSON Schema into ``protocol.schema.json`` beside this file (``python -m vlaprobe.live.protocol``
rewrites it; a test checks it is current), from which the web UI generates its TypeScript types.
docs/live.md explains the flow of messages.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Annotated, Literal

from pydantic import Field, TypeAdapter

from vlaprobe.configs.serve import LiveDriver
from vlaprobe.live.protocol_parts import (
    Alarm,
    BeliefDelta,
    EpisodeSummary,
    Event,
    Flips,
    FlipSet,
    HeadBits,
    HeadFlags,
    HeadInts,
    HeadNames,
    HeadPrediction,
    Prediction,
    ProbeInfo,
    Running,
    StrictModel,
    SubgoalInfo,
    SubgoalState,
    Takeover,
    TakeoverSettings,
    TaskInfo,
    Timings,
    Violation,
)

__all__ = [  # with the parts (vlaprobe.live.protocol_parts), importable from here
    "CLIENT",
    "PROTOCOL_VERSION",
    "SCHEMA_FILE",
    "Alarm",
    "BeliefDelta",
    "ClientMessage",
    "DropCommand",
    "EpisodeEnd",
    "EpisodeListItem",
    "EpisodeRecord",
    "EpisodeStart",
    "EpisodeSummary",
    "ErrorMessage",
    "Event",
    "FlipSet",
    "Flips",
    "HeadBits",
    "HeadFlags",
    "HeadInts",
    "HeadNames",
    "HeadPrediction",
    "Hello",
    "History",
    "PauseCommand",
    "Prediction",
    "ProbeInfo",
    "Protocol",
    "ReplayCommand",
    "ResumeCommand",
    "Running",
    "ServerMessage",
    "StartCommand",
    "Status",
    "Step",
    "StopCommand",
    "SubgoalInfo",
    "SubgoalState",
    "Takeover",
    "TakeoverSettings",
    "TaskInfo",
    "Timings",
    "Violation",
    "schema",
    "schema_text",
]

SCHEMA_FILE = Path(__file__).with_name("protocol.schema.json")
PROTOCOL_VERSION = 5
"""Version of the message set, sent as ``hello.protocol``: 2 added the cognition's alarm and the takeovers
(``--takeover``); 3 the atoms an episode leaves undefined (``episode_start.defined``, their probabilities
null); 4 the takeovers' hand-back (``hello.takeover.until``, ``takeover.ended``); 5 what fires the alarm
(``hello.takeover.on``); a hello without the field is version 1. New fields are optional: a client of an older version reads
the messages it knows."""


# -- server -> client -----------------------------------------------------------------------------
class Hello(StrictModel):
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


class EpisodeStart(StrictModel):
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
    asserted nor scored; clients must not read its 0s as false. Null: every atom is defined (protocol 3; before,
    always null)."""
    subgoals: list[SubgoalInfo]
    goal_objects: list[str] = Field(default_factory=list)
    """The objects and regions the task's goal conjunction names (``TaskGoal.objects``): the UI pins the atoms that
    mention them."""
    store_episode: str | None = None
    """Source "store": the stored episode this one re-runs (every frame at /api/episodes/{it}/frames/{t})."""
    takeover: Literal["none", "alarm", "random"] = "none"
    """Who hands the policy's control to the scripted expert in this episode (hello.takeover's mode)."""


class Step(StrictModel):
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
    """Ground-truth atoms from the detectors; null where the source has none. An atom undefined in the episode
    (``episode_start.defined`` false) is 0 here, neither true nor false: never read it as false."""
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


class History(StrictModel):
    """The episode so far, sent first to a client that joins mid-episode (steps without images)."""

    type: Literal["history"] = "history"
    episode_id: str
    start: EpisodeStart
    steps: list[Step]


class EpisodeEnd(StrictModel):
    type: Literal["episode_end"] = "episode_end"
    episode_id: str
    success: bool
    steps: int
    stopped: bool
    summary: EpisodeSummary


class Status(StrictModel):
    """Sent to every client when the running episode is paused or resumed (late joiners read hello.running)."""

    type: Literal["status"] = "status"
    episode_id: str
    paused: bool


class ErrorMessage(StrictModel):
    type: Literal["error"] = "error"
    message: str


# -- client -> server -----------------------------------------------------------------------------
class StartCommand(StrictModel):
    type: Literal["start"] = "start"
    task: int | str
    """Task index or its instruction (trimmed, any case)."""
    init: int | Literal["random"] = "random"
    driver: LiveDriver = "expert"
    max_steps: int | None = Field(default=None, ge=1, le=10_000)
    """Step budget; null: the server's (--env.max-steps). LIBERO runs at most 1000 steps per episode including
    the settling steps (990 with the default 10): a larger budget is refused with an error."""


class StopCommand(StrictModel):
    type: Literal["stop"] = "stop"


class PauseCommand(StrictModel):
    type: Literal["pause"] = "pause"


class ResumeCommand(StrictModel):
    type: Literal["resume"] = "resume"


class DropCommand(StrictModel):
    type: Literal["drop"] = "drop"
    steps: int | None = Field(default=None, ge=1, le=100)
    """Steps with the gripper forced open; null: the loop's default."""


class ReplayCommand(StrictModel):
    """Stream a stored episode (an id from GET /api/episodes) through the probes and the cognition."""

    type: Literal["replay"] = "replay"
    episode_id: str
    hz: float | None = Field(default=None, ge=0.5, le=60)
    """Steps per second (0.5-60); null: the server's --replay-hz."""


# -- REST -----------------------------------------------------------------------------------------
class EpisodeListItem(StrictModel):
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


class EpisodeRecord(StrictModel):
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


class Protocol(StrictModel):
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
