"""Takeovers in live episodes (``vlaprobe serve --takeover alarm|random``): who asks, and what the messages say.

The mechanism is collection's: the episode runner wraps the policy's driver in
:class:`~vlaprobe.rollout.takeover.TakeoverDriver`, which a takeover is asked of through the episode's control;
the alarm is :class:`~vlaprobe.cognition.alarm.AlarmRule`, the random control
:class:`~vlaprobe.rollout.takeover.RandomTakeovers`, the hand-back under ``--takeover-until subgoal``
:class:`~vlaprobe.cognition.alarm.SubgoalHandBack`. Live, the alarm and the hand-back read the cognition on the
probes' predictions, the one the step message carries (a deployed robot has no other atoms). :class:`LiveTakeovers`
asks; :class:`TakeoverTrack` turns the records' takeovers into the step fields and the episode's summary.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Literal

from vlaprobe.cognition.alarm import Alarm, AlarmRule, SubgoalHandBack
from vlaprobe.cognition.core import CognitionStep
from vlaprobe.configs.takeover import TakeoverConfig
from vlaprobe.live import protocol as P
from vlaprobe.rollout import StepRecord
from vlaprobe.rollout.takeover import RandomTakeovers, Takeover

Handover = Literal["to_expert", "to_policy"]


class LiveTakeovers:
    """Asks for the takeovers of one live episode: when the alarm fires, or at the random control's rows."""

    def __init__(self, cfg: TakeoverConfig, seed: int, max_steps: int) -> None:
        """``seed`` and ``max_steps``: the episode's (they draw the random control's rows)."""
        self.rule = (
            AlarmRule(cfg.takeover_stall, cfg.takeover_hold, cfg.takeover_most, cfg.takeover_on)
            if cfg.takeover == "alarm"
            else None
        )
        self.random = (
            RandomTakeovers(cfg.takeover_count, seed, max_steps, cfg.takeover_steps)
            if cfg.takeover == "random"
            else None
        )
        self.until = SubgoalHandBack() if cfg.takeover_until == "subgoal" else None
        self._request: str | None = None
        self._back: str | None = None

    def observe(self, record: StepRecord, step: CognitionStep) -> Alarm | None:
        """The alarm fired at this step (None under the random control); either asks for a takeover, which
        the expert begins at the next step, and the hand-back asks the policy back for the next step. The last
        row has no next step: nothing is asked there."""
        if record.terminal:
            return None
        if self.until is not None:
            self._back = self.until.check(step, record.takeover)
        alarm = None
        if self.rule is not None:
            alarm = self.rule.check(step, record.takeover is not None)
            reason = None if alarm is None else alarm.text()
        else:
            reason = None if self.random is None else self.random.observe(record)
        if reason is not None:
            self._request = reason
        return alarm

    def take_request(self) -> str | None:
        """The reason of the takeover asked at the latest step, if any (consumes it)."""
        reason, self._request = self._request, None
        return reason

    def take_hand_back(self) -> str | None:
        """The reason of the hand-back asked at the latest step, if any (consumes it)."""
        back, self._back = self._back, None
        return back


def alarm_message(alarm: Alarm | None) -> P.Alarm | None:
    """The step message's ``alarm`` field."""
    if alarm is None:
        return None
    fields = {"kind": alarm.kind, "reason": alarm.reason, "rules": alarm.rules, "atoms": alarm.atoms}
    return P.Alarm.model_validate(fields)


@dataclass
class TakeoverTrack:
    """The takeovers of an episode's records so far, numbered, with their steps."""

    items: list[P.Takeover] = field(default_factory=list)
    _row: int | None = None
    """The start row of the takeover under which the previous record's action was executed."""
    _last: Takeover | None = None
    """The driver's latest takeover (its ``ended`` is set when it hands back, after its last record)."""

    def add(self, record: StepRecord) -> tuple[P.Takeover | None, Handover | None]:
        """This record's takeover (as of this step) and the handover it begins, if any."""
        t = record.takeover
        previous, self._row = self._row, None if t is None else t.row
        if self._last is not None and self.items:
            self.items[-1].ended = self._last.ended or None
        if t is None:
            return None, "to_policy" if previous is not None and not record.terminal else None
        begins = previous != t.row
        if begins:
            self.items.append(P.Takeover(index=len(self.items) + 1, start=t.row, reason=t.reason, steps=0))
        self._last = t
        self.items[-1].steps, self.items[-1].ended = t.steps, t.ended or None
        return self.items[-1].model_copy(), "to_expert" if begins else None

    @property
    def expert_steps(self) -> int:
        return sum(t.steps for t in self.items)
