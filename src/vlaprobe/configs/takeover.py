"""The takeover settings shared by ``vlaprobe collect`` and ``vlaprobe serve`` (``--takeover``)."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Literal

TakeoverMode = Literal["none", "alarm", "random"]
"""Who hands the policy's control to the scripted expert: nobody, the cognition's alarm, or random times."""
TakeoverUntil = Literal["subgoal", "steps"]
"""When the expert hands back: once the subgoal current at the takeover's start is done, or after a fixed count."""
AlarmKind = Literal["stall", "regression", "dropped", "violation"]
"""What may fire the cognition's alarm (``vlaprobe.cognition.alarm.Alarm.kind``)."""
ALARM_KINDS: tuple[AlarmKind, ...] = ("stall", "regression", "dropped", "violation")


@dataclass
class TakeoverConfig:
    """When the scripted expert takes over from the policy (docs/failures.md#the-cognition-takes-over)."""

    takeover: TakeoverMode = "none"
    """"alarm": when the cognition's alarm fires, the scripted expert acts until --takeover-until, then the
    policy again; "random": the same at random (seeded) rows, the control (collect: as many per episode as the
    matching episode of --takeover-match had; serve: --takeover-count); "none": never. Needs --driver policy or
    dagger."""
    takeover_until: TakeoverUntil = "subgoal"
    """"subgoal": the expert hands back once the cognition marks done the subgoal that was current when the
    takeover began (or the goal holds), after at most --takeover-steps actions; "steps": after exactly
    --takeover-steps actions. The random control hands back by the same rule (its cognition reads the same
    atoms as the alarm's), so the conditions differ only in when a takeover starts."""
    takeover_steps: int = 150
    """Under --takeover-until subgoal the cap of a takeover's actions, under steps its length (the episode may
    end first). 150: the scripted expert solves a whole LIBERO-spatial task from the reset in 161 steps on
    average (109-283 over 150 episodes), so one subgoal from wherever the policy left the arm fits,
    while an expert that cannot finish it hands back within half of a 300-step episode."""
    takeover_most: int = 3
    """Most takeovers per episode."""
    takeover_stall: int = 40
    """The alarm fires when no subgoal has been done for this many steps (since the start, the last subgoal
    done or the last hand-back)."""
    takeover_hold: int = 5
    """... or when a consistency rule's violation has held this many steps, or at once on a regression or a
    dropped object (the cognition's events)."""
    takeover_on: tuple[AlarmKind, ...] = ALARM_KINDS
    """--takeover alarm: what fires it (default: all four). "stall" alone, for instance, lets the policy go on
    after a regression or a drop until it stalls."""
    takeover_probes: Path | None = None
    """collect --takeover alarm: the probe folder whose predictions the cognition reads; default: the
    simulator's ground-truth atoms (serve always reads its --probes)."""
    takeover_match: Path | None = None
    """collect --takeover random: the store of the alarm run to match; each episode gets as many takeovers as
    the episode of the same task and init state there, at random rows within its length."""
    takeover_count: int = 1
    """serve --takeover random: takeovers per episode, at random rows within --env.max-steps."""

    def text(self) -> str:
        """The settings that define a store's episodes ("" without takeovers)."""
        if self.takeover == "none":
            return ""
        probes = "truth" if self.takeover_probes is None else str(self.takeover_probes)
        alarm = f" stall={self.takeover_stall} hold={self.takeover_hold} atoms={probes}"
        if tuple(self.takeover_on) != ALARM_KINDS:  # stores before the option: every kind
            alarm += f" on={','.join(self.takeover_on)}"
        until = " until=subgoal" if self.takeover_until == "subgoal" else ""  # stores before it: steps
        return f"{self.takeover}{until} steps={self.takeover_steps} most={self.takeover_most}" + (
            alarm if self.takeover == "alarm" else ""
        )
