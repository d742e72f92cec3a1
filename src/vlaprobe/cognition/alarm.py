"""The cognition's alarm (``--takeover alarm``): when it fires, the scripted expert takes over from the policy.

:class:`AlarmRule` reads the cognition's conclusions step by step and fires, with its reason, on a stall (no
subgoal done for ``stall`` steps since the start, the last subgoal done or the last hand-back), on a
regression or a dropped object (the cognition's events), or on a rule violation held ``hold`` steps. While
the expert acts it stays silent. :class:`SubgoalHandBack` ends a takeover under ``--takeover-until subgoal``:
once the subgoal that was current when the expert took over is done, or the goal holds.
:class:`CognitionSupervisor` runs a cognition on a collected episode's records (ground-truth atoms, or the
probes' predictions), asks for a takeover when the rule fires (or at the random control's rows) and hands
back by the subgoal; :func:`collect` is ``vlaprobe collect`` with that supervisor.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass

import numpy as np

from vlaprobe.cognition.core import Cognition, CognitionStep
from vlaprobe.configs.collect import CollectConfig
from vlaprobe.configs.takeover import ALARM_KINDS, TakeoverConfig
from vlaprobe.envs.base import TaskEnv
from vlaprobe.rollout import StepRecord
from vlaprobe.rollout.takeover import Supervisor, Takeover

REACTIVE = ("regression", "dropped")
"""The cognition's events that fire the alarm at once."""


@dataclass(frozen=True)
class Alarm:
    """Why the alarm fired."""

    kind: str
    """"stall", "regression", "dropped" or "violation"."""
    reason: str
    """One line."""
    rules: tuple[str, ...] = ()
    """The rules whose violations drove it."""
    atoms: tuple[str, ...] = ()
    """The beliefs involved (the violation's atoms, or the stalled subgoal)."""

    def text(self) -> str:
        """The takeover's recorded reason, e.g. ``"stall: no subgoal done for 40 steps (next: ...)"``."""
        return f"{self.kind}: {self.reason}"


class AlarmRule:
    """Fires on stalls, regressions, drops and held violations (those of them in ``on``); at most ``most`` times
    per episode."""

    def __init__(self, stall: int, hold: int, most: int, on: tuple[str, ...] = ALARM_KINDS) -> None:
        self.stall, self.hold, self.most, self.on = stall, hold, most, frozenset(on)
        self.reset()

    def reset(self) -> None:
        self.fired, self._since, self._level = 0, 0, -1.0

    def check(self, step: CognitionStep, acting: bool) -> Alarm | None:
        """The alarm at this step, or None (``acting``: the expert executed this step's action)."""
        t = step.t
        if step.progress != self._level:
            self._level, self._since = step.progress, t
        if acting:
            self._since = t  # the stall counts from the hand-back
            return None
        if self.fired >= self.most or step.goal_reached:
            return None
        alarm = self._why(step, t)
        if alarm is not None:
            self.fired += 1
            self._since = t
        return alarm

    def _why(self, step: CognitionStep, t: int) -> Alarm | None:
        for e in step.events:
            if e.kind in REACTIVE and e.kind in self.on:
                return Alarm(e.kind, e.message.removeprefix(f"{e.kind}: "))  # text() prefixes the kind
        held = [v for v in step.violations if t - v.since + 1 >= self.hold]
        if held and "violation" in self.on:
            rules = tuple(sorted({v.rule for v in held}))
            atoms = tuple(sorted({a for v in held for a in v.atoms}))
            return Alarm("violation", held[0].message, rules, atoms)
        if t - self._since >= self.stall and "stall" in self.on:
            active = next((g.name for g in step.subgoals if g.status != "done"), "")
            return Alarm(
                "stall", f"no subgoal done for {t - self._since} steps (next: {active})", (), (active,)
            )
        return None


class SubgoalHandBack:
    """``--takeover-until subgoal``: the hand-back once the subgoal current at a takeover's start is done.

    The current subgoal is the first one not done on the takeover's first row (the observation on which the
    expert first acts); the hand-back is asked on the first later row whose beliefs mark it done, or where the
    goal holds, and the policy acts from the next action on."""

    def __init__(self) -> None:
        self._row: int | None = None
        self._index, self._name = 0, ""

    def check(self, step: CognitionStep, takeover: Takeover | None) -> str | None:
        """The hand-back's reason after this step, or None (``takeover``: the one the expert executed this
        step's action under; None when the policy acted)."""
        if takeover is None:
            self._row = None
            return None
        if takeover.row != self._row:
            self._row = takeover.row
            current = next((g for g in step.subgoals if g.status != "done"), None)
            self._index, self._name = (0, "") if current is None else (current.index, current.name)
        if step.goal_reached:
            return "goal"
        done = any(g.index == self._index and g.status == "done" for g in step.subgoals)
        return f"subgoal: {self._name}" if done else None


class CognitionSupervisor:
    """The alarm of one collected episode: a cognition on its records' atoms (or the probes' predictions)."""

    def __init__(
        self, env: TaskEnv, cfg: TakeoverConfig, model_id: str, trigger: Supervisor | None = None
    ) -> None:
        """``model_id``: the model whose hidden states the records carry (``--takeover-probes`` must be its);
        ``trigger``: who asks for takeovers instead of the alarm (the random control, whose takeovers the
        cognition hands back by the same rule)."""
        from vlaprobe.cognition.readout import ProbeReadout

        vocab = env.labeler.vocabulary
        probes = cfg.takeover_probes
        self.readout = None if probes is None else ProbeReadout.load(probes, model_id=model_id)
        probed = None if self.readout is None else self.readout.probed
        self.cognition = Cognition(vocab.object_atoms, vocab.action_atoms, env.goal, probed=probed)
        self.rule = AlarmRule(cfg.takeover_stall, cfg.takeover_hold, cfg.takeover_most, cfg.takeover_on)
        self.trigger = trigger
        self.until = SubgoalHandBack() if cfg.takeover_until == "subgoal" else None
        self._back: str | None = None

    def observe(self, record: StepRecord) -> str | None:
        if self.readout is None:
            obj, act = np.asarray(record.object_atoms), np.asarray(record.action_atoms)
        else:
            a = self.readout.assign(record.hidden)
            obj, act = a.values["object"], a.values["action"]
        step = self.cognition.step(obj, act)
        self._back = None if self.until is None else self.until.check(step, record.takeover)
        if self.trigger is not None:
            return self.trigger.observe(record)
        alarm = self.rule.check(step, record.takeover is not None)
        return None if alarm is None else alarm.text()

    def hand_back(self) -> str | None:
        return self._back


def collect(cfg: CollectConfig) -> object:
    """``vlaprobe collect``: with ``--takeover``, the workers ask the cognition (the alarm; the hand-back)."""
    from vlaprobe.collection.collect import collect as run
    from vlaprobe.collection.worker import Worker

    if cfg.intervention.takeover == "none":
        return run(cfg)
    return run(cfg, functools.partial(Worker, make_supervisor=CognitionSupervisor))
