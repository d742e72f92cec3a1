"""`vlaprobe cognition`'s result: the figures it measures and ``monitor.json`` (written and read here)."""

from __future__ import annotations

import json
import math
from dataclasses import asdict, dataclass, field
from pathlib import Path

import dacite

from vlaprobe.cognition.monitor_inputs import SkippedEpisode
from vlaprobe.files import JsonObject, from_json, read_versioned, write_atomic

MONITOR_FILE = "monitor.json"


@dataclass(frozen=True)
class ViolationFigures:
    """Violations of one run (truth or probes) over all episodes."""

    violations_per_100_steps: float
    violations: dict[str, int]
    """Rule id -> violations that appeared (every shipped rule listed, 0 included)."""


@dataclass(frozen=True)
class GoalDetection:
    """Goal reached from predictions vs from truth, over episodes that succeed and episodes that fail."""

    precision: float | None
    """Of the episodes where the predictions reached the goal, the share where truth did too (None: none did)."""
    recall: float | None
    """Of the episodes where truth reached the goal, the share where the predictions did too."""
    mean_delay_steps: float | None
    """Mean of (predicted step - true step) over episodes where both reached it; negative: early."""
    false_alarms_per_100_steps: float | None = None
    """``goal_reached`` events from the predictions at a step where truth's goal was not reached, per 100 steps."""
    episodes: int = 0
    """Episodes the figures rest on."""
    failed_episodes: int = 0
    """Of them, episodes in which truth never reached the goal (precision means little without any)."""


@dataclass(frozen=True)
class ProbeFigures(ViolationFigures):
    """The run on the probes' predictions, compared with the run on truth."""

    goal_detection: GoalDetection = field(default_factory=lambda: GoalDetection(None, None, None))
    subgoal_accuracy: float = math.nan
    """Share of steps whose active subgoal (predictions) equals the one from truth."""
    belief_agreement: float = math.nan
    """Share of (step, probed atom) pairs whose belief (predictions) equals the belief from truth."""
    belief_agreement_step0: float = math.nan
    """The same for a predictor that keeps each episode's step-0 beliefs from truth: the bar for agreement
    (on expert episodes most atoms never change, so agreement alone says little)."""
    belief_agreement_gain_95: tuple[float, float] | None = None
    """95% bootstrap interval over episodes (1000 resamples, seed 0) of agreement minus the step-0 bar."""
    flips_per_step: float = math.nan
    """Changes of probed atoms between consecutive steps in the raw predictions, per step."""
    flips_per_step_debounced: float = math.nan
    """The same in the debounced beliefs."""


@dataclass(frozen=True)
class EpisodeFigures:
    """One episode's comparison."""

    key: str
    steps: int
    goal_step_truth: int | None
    goal_step_probes: int | None
    false_alarms: int
    """``goal_reached`` events of the predictions at steps where truth's goal was not reached."""
    violations_truth: int
    violations_probes: int
    subgoal_accuracy: float


@dataclass(frozen=True)
class MonitorResult:
    """What `vlaprobe cognition` measured (the JSON printed with --json is :meth:`summary`)."""

    episodes: int
    steps: int
    truth: ViolationFigures
    probes: ProbeFigures
    held_out: bool
    """Whether the episodes are held out from the probes' training (False with --all-episodes or refit probes)."""
    layers: dict[str, int]
    debounce: int
    rules: list[str]
    per_episode: list[EpisodeFigures]
    skipped: list[SkippedEpisode] = field(default_factory=list)
    """Episodes left out: their goal names an atom the vocabulary lacks (e.g. a push onto a table region)."""
    unknown_heads: list[str] = field(default_factory=list)
    """Heads the probes lack (``train`` skipped them): their atoms were read as unknown (not probed, false)."""

    def gaps(self) -> list[str]:
        """One line per thing the cognition could not do (episodes left out, a head read as unknown)."""
        lines = []
        if self.skipped:
            shown = "; ".join(f"{s.key} (task {s.task}): {s.reason}" for s in self.skipped[:3])
            more = f"; and {len(self.skipped) - 3} more" if len(self.skipped) > 3 else ""
            lines.append(f"{len(self.skipped)} episode(s) left out, goal not followable: {shown}{more}")
        for head in self.unknown_heads:
            lines.append(
                f"the probes have no {head} head: the cognition ran on the other head alone, {head} beliefs unknown"
            )
        return lines

    def summary(self) -> JsonObject:
        """The figures of the issue's JSON: episodes, steps, truth, probes."""
        return {
            "episodes": self.episodes,
            "steps": self.steps,
            "truth": asdict(self.truth),
            "probes": asdict(self.probes),
        }

    def to_json(self) -> JsonObject:
        """``monitor.json``: this result with its format and version (:func:`write_monitor`)."""
        return {"format": MONITOR_FORMAT, "format_version": MONITOR_FORMAT_VERSION, **asdict(self)}


MONITOR_FORMAT = "vlaprobe-monitor"
MONITOR_FORMAT_VERSION = 3
"""Version 2 added goal detection's false alarms and episode counts (and each episode's ``false_alarms``); a
version-1 file is read with those at their defaults (an episode's false alarms as 0: not counted then). Version 3
added the episodes left out (``skipped``) and the heads read as unknown (``unknown_heads``); older files read
with none."""


def write_monitor(folder: str | Path, result: MonitorResult) -> Path:
    """Write ``<folder>/monitor.json`` atomically; return its path."""
    path = Path(folder) / MONITOR_FILE
    write_atomic(path, json.dumps(result.to_json(), indent=1) + "\n")
    return path


def read_monitor(folder: str | Path) -> MonitorResult:
    """Read ``<folder>/monitor.json``; a one-line error if it is missing, damaged or of an unknown version
    (a file without a version reads as version 1, whose episodes did not count false alarms: 0)."""
    path = Path(folder) / MONITOR_FILE
    hint = "run vlaprobe cognition again"
    data, version = read_versioned(
        path, MONITOR_FORMAT, "monitor file", (1, 2, MONITOR_FORMAT_VERSION), hint, unversioned=1
    )  # versions 1 and 2 have no skipped episodes nor unknown heads: read as none
    data = {k: v for k, v in data.items() if k not in ("format", "format_version")}
    if version == 1:
        for episode in data.get("per_episode") or []:
            if isinstance(episode, dict):
                episode.setdefault("false_alarms", 0)
    return from_json(MonitorResult, data, path, hint, dacite.Config(check_types=False, cast=[tuple]))
